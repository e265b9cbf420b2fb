"""An SSM shield cycle's plans and checks in one compiled call (``Shield._plan_and_verify``).

The shielded trajectory at the follower's cap and its robot capsules
(:func:`~sara_app.robot.shielded_kernels.plan_at_cap`: the kernels of ``PathFollower.peek``,
``shielded_trajectory`` and ``RobotOccupancy.intervals`` with the tracking margin), its check
against every person (:func:`~sara_app.safety.ssm_kernels.ssm_kernel`), and while the check
fails, the speed scaling's replans (``cut`` x the lower of the last cap and the trajectory's
largest path speed, down to ``c_min``; at most ``max_replans``): the decisions of
``Shield._plan_and_verify``, whose Python composition of the same kernels
(``Shield._composed``) runs where this one declines and is its oracle in the tests (the same
bits). It declines (``PYTHON``) a plan it cannot sample: a step that falls back on the held
failsafe, a non-finite stop, a trajectory the occupancy kernel rejects. Asked for, it also
reports the separation at the command (the last plan's sample 1, from the capsule ends its
occupancy computed: :func:`~sara_app.safety.distance_kernels.separation`, as
``Shield.min_distance`` computes it at that configuration). Numba's cache checks only this
file: the source digests of the files whose kernels it calls are a closure variable.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

from sara_app.geometry import shape_kernels
from sara_app.human import reach_kernels
from sara_app.kernel_types import B1, F8, I8, RO1, ROI1, ROI2, W1, source_digest
from sara_app.robot import occupancy_kernels, planning_kernels, shielded_kernels, trajectory_kernels
from sara_app.robot.shielded_kernels import (
    FOLLOWER,
    OCCUPANCY,
    PATH,
    PLANNER,
    plan_at_cap,
    plan_views,
)
from sara_app.safety import distance_kernels, ssm_kernels
from sara_app.safety.distance_kernels import separation
from sara_app.safety.ssm_kernels import ARM, CONSTANTS, HUMAN, ssm_kernel

__all__ = ["DISTANCE", "DONE", "PYTHON", "ssm_cycle_kernel"]

DONE, PYTHON = 0, 1
"""Return codes: the cycle's last check is in the outputs / a plan the kernel cannot sample
(the caller runs the Python composition instead)."""

DISTANCE = types.Tuple((B1, RO1, ROI2, RO1))
"""``(wanted, link radii (L,), part_joints (P, 2), half thicknesses (P,))``: the separation at
the command (``Shield.min_distance``'s constants)."""


def _make_kernel() -> Any:
    """Build :func:`ssm_cycle_kernel` with its callees' source digests in the closure."""
    sources = "".join(
        source_digest(m)
        for m in (
            shape_kernels, reach_kernels, occupancy_kernels, planning_kernels,
            trajectory_kernels, shielded_kernels, ssm_kernels,
            distance_kernels,
        )
    )  # fmt: skip
    B3 = types.Array(types.boolean, 3, "C")
    C2, C3, C4 = (types.Array(F8, d, "C") for d in (2, 3, 4))
    result = types.Tuple((I8, C2, C3, C3, C4, C2, B3, B3, C2, B3))

    @njit(
        result(FOLLOWER, PLANNER, PATH, types.UniTuple(F8, 2), OCCUPANCY, HUMAN, CONSTANTS, ROI1,
               ROI2, ARM, types.UniTuple(F8, 3), I8, DISTANCE, W1, W1),
        cache=True,
    )  # fmt: skip
    def ssm_cycle_kernel(
        follower: Any,
        planner: Any,
        path: Any,
        sampling: Any,
        occupancy: Any,
        human: Any,
        constants: Any,
        codes: np.ndarray,
        part_maps: np.ndarray,
        arm: Any,
        control: Any,
        max_replans: int,
        distance: Any,
        info: np.ndarray,
        out: np.ndarray,
    ) -> Any:
        """From the plan at ``control = (cap0, c_min, cut)``'s ``cap0``: check, and replan
        while the check fails (see the module notes). Returns ``(code, pts, joint, bounds,
        ends, radius, free, evaluated, closest, parts)``: the last plan's views of its slab
        (:func:`~sara_app.robot.shielded_kernels.plan_views`, less the record) and its
        check's arrays (as :class:`~sara_app.safety.ssm.SsmResult`); ``out (OUT_LEN,)``: the
        last plan's ``peek_kernel`` record; ``info (6,)``: the last check's verdict (0/1), the
        cap of the replans (inf: none), checks, the last plan's ``peek_kernel`` status, the
        last model the last check evaluated (its index in ``codes``; -1: none), the separation
        at the command (``distance``; NaN where not wanted or ``code`` is not ``DONE``)."""
        cap0, c_min, cut = control
        H, M = human[0].shape[0], codes.shape[0]
        P = part_maps.shape[1]
        out[:] = 0.0
        empty = np.zeros((0, 0, 0), np.bool_)
        code = PYTHON if len(sources) == 0 else DONE  # the digests tie the cache to the callees
        ok, status, robot, trajectory, slab, E = plan_at_cap(
            cap0, follower, planner, path, sampling, occupancy, out
        )
        L, n = occupancy[5].shape[0], occupancy[0].shape[0]
        if not ok:
            _, pts, joint, bounds, ends, radius = plan_views(slab, robot[1].shape[0], L, n)
            return PYTHON, pts, joint, bounds, ends, radius, empty, empty, np.zeros((0, 0)), empty
        cap, checks = np.inf, 0
        while True:
            K = robot[1].shape[0]
            free = np.empty((H, M, K), np.bool_)
            evaluated = np.empty((H, M, K), np.bool_)
            closest = np.empty((H, M))
            parts = np.empty((H, K, P), np.bool_)
            safe = ssm_kernel(human, constants, codes, part_maps, arm, trajectory[4], robot[0],
                              robot[1], free, evaluated, closest, parts)  # fmt: skip
            checks += 1
            if safe or checks > max_replans:
                break
            top = trajectory[2].max()
            cand = cut * min(cap, top)
            if not cand >= c_min:  # NaN too
                break
            cap = cand
            ok, status, robot, trajectory, slab, E = plan_at_cap(
                cap, follower, planner, path, sampling, occupancy, out
            )
            if not ok:
                code = PYTHON
                break
        info[0], info[1], info[2], info[3] = 1.0 if safe else 0.0, cap, checks, status
        info[4] = -1.0
        wanted, link_radius, part_joints, half = distance
        info[5] = math.nan
        if wanted and code == DONE:
            info[5] = separation(E, 1, link_radius, human[0], part_joints, half)
        for m in range(M):
            for h in range(H):
                for k in range(evaluated.shape[2]):
                    if evaluated[h, m, k]:
                        info[4] = m
        _, pts, joint, bounds, ends, radius = plan_views(slab, robot[1].shape[0], L, n)
        return code, pts, joint, bounds, ends, radius, free, evaluated, closest, parts

    return ssm_cycle_kernel


ssm_cycle_kernel = _make_kernel()
