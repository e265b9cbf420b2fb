"""The compiled checks and replans of a PFL shield cycle (:mod:`sara_app.safety.pfl_cycle`).

From the trajectory the shield planned at the held cap: its check
(:func:`~sara_app.safety.pfl_fused_kernels.fused_kernel`), and while a check fails and a replan
can fix it, the plan at the lower cap (:func:`~sara_app.robot.planning_kernels.peek_kernel`,
:func:`~sara_app.robot.trajectory_kernels.shielded_samples_kernel`,
:func:`~sara_app.robot.occupancy_kernels.intervals_kernel`: the kernels of
``PathFollower.peek``, ``shielded_trajectory`` and ``RobotOccupancy.intervals``) and its check,
with the shield's decisions (model budget, replan rule, model orders). Compared cycle by cycle
with the Python composition of the same kernels in ``tests/pfl_reference.py`` (the same bits).
A replan the follower cannot plan (it falls back on its held failsafe, a non-finite stop, a
rejected trajectory) ends the loop: the failed check's verdict stands and the shield brakes. Numba's
cache checks only this file: the source digests of the files whose kernels it calls are a
closure variable.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

from sara_app.geometry import shape_kernels
from sara_app.human import reach_kernels
from sara_app.kernel_types import F8 as _f8
from sara_app.kernel_types import I8 as _i8
from sara_app.kernel_types import RO1 as _RO1
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import RO3 as _RO3
from sara_app.kernel_types import ROI1 as _ROI1
from sara_app.kernel_types import W1 as _W1
from sara_app.kernel_types import WI2 as _WI2
from sara_app.kernel_types import source_digest
from sara_app.robot import (
    crba_kernels,
    energy,
    occupancy_kernels,
    planning_kernels,
    trajectory_kernels,
)
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
)
from sara_app.robot.trajectory_kernels import shielded_samples_kernel
from sara_app.safety import contact_kernels, pfl_fused_kernels, pfl_kernels, pfl_link_states
from sara_app.safety.pfl_fused_kernels import (
    HUMAN,
    LINK_CONSTANTS,
    MODELS,
    ROBOT,
    TRAJECTORY,
    check_buffers,
    check_results,
    frames,
    fused_kernel,
    replan_cap,
)

__all__ = ["BAIL", "DONE", "cycle_kernel", "plan_views"]

DONE, BAIL = 0, 1
"""Return codes: the loop ran to its end / a check ended in a state a classification cannot
produce (unproved entries without link energies: the caller faults the cycle)."""


FOLLOWER = types.UniTuple(_f8, 8)
"""``(s, s', s'', dt, S, A_min, J_min, ramp_c)``: the follower's state and look-ahead constants."""
PLANNER = types.Tuple((_RO2, _RO3, _RO3, _RO1))
"""``(pc, rows, geo, consts)``: the follower's path as ``peek_kernel`` reads it."""
PATH = types.Tuple((_RO1, _RO1, _RO3, _RO2, _RO2, _RO2))
"""The path's piece tables as ``shielded_samples_kernel`` reads them."""
OCCUPANCY = types.Tuple((_ROI1, _RO3, _ROI1, _ROI1, _RO3, _RO2, _RO1, _RO2, _RO1))
"""``(q_index, N, parents, link_joint, ends_joint, lipschitz, radius0, T_world_base (4, 4),
tracking margin (L,))``: the shield's robot occupancy per interval."""


@njit(cache=True)
def _record_start(out: np.ndarray, off: int, cap: int) -> tuple[int, float, float, float]:
    """Phase count and start state ``(s, s', s'')`` of a profile record of ``peek_kernel``."""
    n = int(out[off])
    t = off + 1 + 2 * cap
    c = cap + 1
    return n, out[t + c], out[t + 2 * c], out[t + 3 * c]


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
def _plan(
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
    n_h, s0, v0, a0 = _record_start(out, O_HEAD, H_CAP)
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
def _to_front(row: np.ndarray, i: int) -> None:
    """``order.insert(0, order.pop(i))`` on an array row."""
    x = row[i]
    for j in range(i, 0, -1):
        row[j] = row[j - 1]
    row[0] = x


@njit(cache=True)
def _to_back(row: np.ndarray) -> None:
    """``order.append(order.pop(0))`` on an array row."""
    x = row[0]
    for j in range(row.shape[0] - 1):
        row[j] = row[j + 1]
    row[row.shape[0] - 1] = x


def _make_kernel() -> Any:
    """Build :func:`cycle_kernel` with its callees' source digests in the closure."""
    sources = "".join(
        source_digest(m)
        for m in (
            shape_kernels, reach_kernels, crba_kernels, energy, occupancy_kernels,
            planning_kernels, trajectory_kernels, contact_kernels, pfl_kernels,
            pfl_link_states, pfl_fused_kernels,
        )
    )  # fmt: skip

    @njit(
        (
            ROBOT, TRAJECTORY, FOLLOWER, PLANNER, PATH, types.UniTuple(_f8, 2), OCCUPANCY,
            LINK_CONSTANTS, _RO2, MODELS, HUMAN, types.UniTuple(_f8, 3),
            types.UniTuple(_i8, 2), _WI2, _W1,
        ),
        cache=True,
    )  # fmt: skip
    def cycle_kernel(
        robot1: Any,
        trajectory1: Any,
        follower: Any,
        planner: Any,
        path: Any,
        sampling: Any,
        occupancy: Any,
        link_constants: Any,
        T0_links: np.ndarray,
        models: Any,
        human: Any,
        control: Any,
        limits: Any,
        orders: np.ndarray,
        info: np.ndarray,
    ) -> Any:
        """The loop (see the module notes) from the trajectory planned at ``control = (cap,
        c_min, cut)``; ``limits = (max_replans, max_models)``, ``orders (2, M)`` the model codes
        of a cycle's first check and of its replans (updated in place), ``info (9,)``: the last
        checked trajectory's cap, the cap for the next cycle (NaN: none set), checks, models
        of the last check, eq. 6 (0/1), the allowed speed of a verified last check, the last
        replan's ``peek_kernel`` status, whether the orders changed (0/1), the model evaluations
        of the cycle. ``models``: the check's constants (:data:`pfl_fused_kernels.MODELS`).
        Returns ``(code, plan, check)``: the last replan's slab (:func:`plan_views`; empty when
        there was none) and the last check's ``(slabs, state)`` (see
        :func:`~sara_app.safety.pfl_fused_kernels.check_results`)."""
        cap, c_min, cut = control
        max_replans, max_models = limits
        M = orders.shape[1]
        r_ends, r_radius, T_box, half, s_radius = robot1
        L, P, B = r_radius.shape[1], models[7].shape[1], T_box.shape[0]
        H = human[0].shape[0]
        C, n = models[4][3].shape[0], trajectory1[0].shape[1]
        out = np.zeros(OUT_LEN)
        robot = (r_ends.copy(), r_radius.copy())
        q, dq, sd, sd_max, times, v_bound, a_bound = trajectory1
        trajectory = (q.copy(), dq.copy(), sd.copy(), sd_max.copy(), times.copy(),
                      v_bound.copy(), a_bound.copy())  # fmt: skip
        plan = np.empty(0)
        slabs, first, verdict, state = check_results(0, L, H * P)
        checks, left = 0, max_models
        new_cap = math.nan
        plan_status = STEP
        info[7] = 0
        code = DONE if len(sources) > 0 else BAIL  # the digests tie the cache to the callees
        while code == DONE:
            K = robot[1].shape[0]
            geometry, links, sets, scratch = check_buffers(K, L, P, H, B, C, n, T0_links)
            slabs, first, verdict, state = check_results(K, L, H * P)
            row = orders[1 if checks > 0 else 0]
            lazy = checks < max_replans and left > 1
            robot_k = (robot[0], robot[1], T_box, half, s_radius)
            done = fused_kernel(
                robot_k, geometry, trajectory, link_constants, links, models, human, sets,
                row, min(M, left), False, (lazy, cap, c_min, cut), first, scratch, verdict, state,
            )  # fmt: skip
            if done == -2:
                code = BAIL
                break
            if done > 0:
                _to_front(row, done)
                info[7] = 1
            used = state[0]
            left -= used
            checks += 1
            if state[5] == 1:
                break
            # a replan within the cycle: cut x the current speed; the cap held after the
            # cycle's last check: the energies' candidate (pfl_scaling's notes)
            guess = verdict[9][0] if checks > max_replans else math.inf
            cand = replan_cap(guess, (True, cap, c_min, cut), trajectory[2])
            if lazy and used == 1 and M > 1:  # stopped for the replan: next time another first
                _to_back(row)
                info[7] = 1
            if not cand >= c_min:  # NaN too
                new_cap = c_min
                break
            new_cap = cand
            if state[6] == 1 or checks > max_replans or left < 1:
                break
            ok, status, robot_c, trajectory_c, plan_c, _ = _plan(
                cand, follower, planner, path, sampling, occupancy, out
            )
            if not ok:  # no slower plan to check: the failed check's verdict stands (brake)
                break
            cap, plan_status, robot, trajectory, plan = cand, status, robot_c, trajectory_c, plan_c
        info[0], info[1], info[2], info[3] = cap, new_cap, checks, state[0]
        info[4], info[5], info[6] = state[5], verdict[9][1], plan_status
        info[8] = max_models - left
        return code, plan, (slabs, state)

    return cycle_kernel


cycle_kernel = _make_kernel()
