"""The follower's shielded trajectory at a path-speed cap and its robot capsules per interval,
planned in one compiled call (:func:`plan_at_cap`): what the compiled SSM and PFL cycles
(:mod:`~sara_app.safety.ssm_cycle_kernels`, :mod:`~sara_app.safety.pfl_cycle_kernels`) replan
with. The kernels of ``PathFollower.peek`` (:func:`~sara_app.robot.planning_kernels.peek_kernel`),
``shielded_trajectory``
(:func:`~sara_app.robot.trajectory_kernels.shielded_samples_kernel`) and
``RobotOccupancy.intervals`` (:func:`~sara_app.robot.occupancy_kernels.intervals_kernel`) in
sequence, the plan's arrays in one slab (:func:`plan_views`). Neither cycle's checks are here:
a process that runs SSM loads no PFL kernel (about 0.3 s of a worker's start).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

from sara_app.kernel_types import F8 as _f8
from sara_app.kernel_types import I8 as _i8
from sara_app.kernel_types import RO1 as _RO1
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import RO3 as _RO3
from sara_app.kernel_types import ROI1 as _ROI1
from sara_app.kernel_types import W1 as _W1
from sara_app.kernel_types import source_digest
from sara_app.robot import planning_kernels
from sara_app.robot.occupancy_kernels import intervals_kernel
from sara_app.robot.planning_kernels import (
    FALLBACK,
    H_CAP,
    O_HEAD,
    O_STOP,
    OUT_LEN,
    S_CAP,
    STEP,
    peek_kernel,
    record_start,
)
from sara_app.robot.trajectory_kernels import shielded_samples_kernel

__all__ = [
    "FOLLOWER", "OCCUPANCY", "PATH", "PLANNER", "frames", "plan_at_cap", "plan_size", "plan_views",
]  # fmt: skip


FOLLOWER = types.UniTuple(_f8, 8)
"""``(s, s', s'', dt, S, A_min, J_min, ramp_c)``: the follower's state and look-ahead constants."""
PLANNER = types.Tuple((_RO2, _RO3, _RO3, _RO1))
"""``(pc, rows, geo, consts)``: the follower's path as ``peek_kernel`` reads it."""
PATH = types.Tuple((_RO1, _RO1, _RO3, _RO2, _RO2, _RO2))
"""The path's piece tables as ``shielded_samples_kernel`` reads them."""
OCCUPANCY = types.Tuple((_ROI1, _RO3, _ROI1, _ROI1, _RO3, _RO2, _RO1, _RO2, _RO1))
"""``(q_index, N, parents, link_joint, ends_joint, lipschitz, radius0, T_world_base (4, 4),
tracking margin (L,))``: the shield's robot occupancy per interval."""


def _make_plan_kernels() -> tuple[Any, Any]:
    """Build :func:`plan_size` and :func:`plan_views`. They read ``planning_kernels.OUT_LEN``,
    which numba freezes into the compiled code: that module's source digest is a closure
    variable (hashed into numba's cache key), so a change there recompiles them. Uncached,
    they were compiled at every import: 0.45 s in every process that imports this module."""
    planning_source = source_digest(planning_kernels)

    @njit(types.int64(_i8, _i8, _i8), cache=True)
    def plan_size(K: int, L: int, n: int) -> int:
        """Length of the slab of a plan of ``K`` intervals (see :func:`plan_views`)."""
        if len(planning_source) == 0:  # never: ties the cache to planning_kernels.py
            raise ValueError("no planning_kernels source digest")
        S = K + 1
        return OUT_LEN + 5 * S + 5 * S * n + 2 * K * n + 6 * K * L + K * L

    @njit(
        types.Tuple(
            (_W1, types.Array(_f8, 2, "C"), types.Array(_f8, 3, "C"), types.Array(_f8, 3, "C"),
             types.Array(_f8, 4, "C"), types.Array(_f8, 2, "C"))
        )(types.Array(_f8, 1, "C"), _i8, _i8, _i8),
        cache=True,
    )  # fmt: skip
    def plan_views(slab: np.ndarray, K: int, L: int, n: int) -> Any:
        """The arrays of a plan in its slab (one array to return to Python instead of six):
        ``peek_kernel``'s record ``(OUT_LEN,)``, times | s | s' | s'' | sd_max (``K`` used)
        ``(5, K+1)``, joint states ``(5, K+1, n)`` (q, dq/ds, d2q/ds2, v, a), bounds ``(2, K,
        n)``, robot capsules ``(K, L, 2, 3)``, ``(K, L)``."""
        if len(planning_source) == 0:  # never: ties the cache to planning_kernels.py
            raise ValueError("no planning_kernels source digest")
        S = K + 1
        o = OUT_LEN
        pts = slab[o : o + 5 * S].reshape((5, S))
        o += 5 * S
        joint = slab[o : o + 5 * S * n].reshape((5, S, n))
        o += 5 * S * n
        bounds = slab[o : o + 2 * K * n].reshape((2, K, n))
        o += 2 * K * n
        r_ends = slab[o : o + 6 * K * L].reshape((K, L, 2, 3))
        o += 6 * K * L
        return slab[:OUT_LEN], pts, joint, bounds, r_ends, slab[o : o + K * L].reshape((K, L))

    return plan_size, plan_views


plan_size, plan_views = _make_plan_kernels()


@njit  # calls kernels of other files: compiled into its callers (kernel_types, caching)
def plan_at_cap(
    cap: float,
    follower: Any,
    planner: Any,
    path: Any,
    sampling: Any,
    occupancy: Any,
    out: np.ndarray,
) -> Any:
    """The shielded trajectory at path-speed cap ``cap`` and its robot capsules per interval
    (``Shield._shielded`` with the follower's cap set): ``(ok, status, robot arrays,
    trajectory arrays, slab, E)`` (``slab``: the plan's arrays in one, see :func:`plan_views`;
    ``E (K+1, L, 2, 3)``: the link capsules' ends at the samples, written where ``ok``);
    ``ok`` False where there is no plan to check, ``status`` ``peek_kernel``'s."""
    s, v, a, dt, S, A_min, J_min, ramp_c = follower
    pc, rows, geo, consts = planner
    bound_pad, max_interval_s = sampling
    q_index, N, parents, link_joint, ends_joint, lipschitz, radius0, T0, margin = occupancy
    status = peek_kernel(s, v, a, dt, cap, S, A_min, J_min, ramp_c, pc, rows, geo, consts, out)
    n_h, s0, v0, a0 = record_start(out, O_HEAD, H_CAP)
    n_s, T = 0, 0.0  # the rest stop (STEP_REST): no phases
    if status == STEP:
        n_s = int(out[O_STOP])
        T = out[O_STOP + 1 + 2 * S_CAP + n_s]
    ok = status != FALLBACK and math.isfinite(T)
    m = 0
    if ok and T > 0.0:
        m = max(1, int(math.ceil(T / max_interval_s - 1e-9)))
    K = m + 1
    n, L = rows.shape[1], lipschitz.shape[0]
    phases = np.empty(2 * (n_h + n_s))
    for i in range(n_h):
        phases[i] = out[O_HEAD + 1 + i]
        phases[n_h + n_s + i] = out[O_HEAD + 1 + H_CAP + i]
    for i in range(n_s):
        phases[n_h + i] = out[O_STOP + 1 + i]
        phases[2 * n_h + n_s + i] = out[O_STOP + 1 + S_CAP + i]
    slab = np.empty(plan_size(K, L, n))
    record, pts, joint, bounds, r_ends, r_radius = plan_views(slab, K, L, n)
    record[:] = out
    times, ps, sd_max = pts[0], pts[1:4], pts[4, :K]
    E = np.empty((K + 1, L, 2, 3))
    if ok:
        p_s0, p_len, poly, M1, M2, qs = path
        shielded_samples_kernel(dt, T, s0, v0, a0, phases, p_s0, p_len, poly, M1, M2, qs,
                                bound_pad, times, ps, joint, bounds, sd_max)  # fmt: skip
        Qj = np.empty((K + 1, n))
        for r in range(K + 1):
            for j in range(n):
                Qj[r, j] = joint[0, r, q_index[j]]
        H = frames(K + 1, n, T0)
        code = intervals_kernel(Qj, bounds[0], times, N, parents, link_joint, ends_joint,
                                lipschitz, radius0, H, E, r_ends, r_radius)  # fmt: skip
        ok = code == 0
        for k in range(K):
            for i in range(L):
                r_radius[k, i] += margin[i]
    robot = (r_ends, r_radius)
    trajectory = (joint[0], joint[1], pts[2], sd_max, times, bounds[0], bounds[1])
    return ok, status, robot, trajectory, slab, E


@njit(cache=True)
def frames(S: int, n: int, T0: np.ndarray) -> np.ndarray:
    """Joint-frame buffers ``(S, n+1, 4, 4)`` as the forward kinematics expects them: frame 0
    the base pose ``T0``, the others' last row ``[0, 0, 0, 1]`` (the kernels write the rest)."""
    H = np.zeros((S, n + 1, 4, 4))
    for r in range(S):
        H[r, 0] = T0
        for j in range(1, n + 1):
            H[r, j, 3, 3] = 1.0
    return H
