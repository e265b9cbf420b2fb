"""The compiled checks and replans of a PFL shield cycle (:mod:`sara_app.safety.pfl_cycle`).

From the trajectory the shield planned at the held cap: its check
(:func:`~sara_app.safety.pfl_fused_kernels.fused_kernel`), and while a check fails and a replan
can fix it, the plan at the lower cap (:func:`~sara_app.robot.shielded_kernels.plan_at_cap`:
the kernels of ``PathFollower.peek``, ``shielded_trajectory`` and ``RobotOccupancy.intervals``)
and its check,
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
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import W1 as _W1
from sara_app.kernel_types import WI2 as _WI2
from sara_app.kernel_types import source_digest
from sara_app.robot import (
    crba_kernels,
    energy,
    occupancy_kernels,
    planning_kernels,
    shielded_kernels,
    trajectory_kernels,
)
from sara_app.robot.planning_kernels import OUT_LEN, STEP
from sara_app.robot.shielded_kernels import FOLLOWER, OCCUPANCY, PATH, PLANNER, plan_at_cap
from sara_app.safety import contact_kernels, pfl_fused_kernels, pfl_kernels, pfl_link_states
from sara_app.safety.pfl_fused_kernels import (
    HUMAN,
    LINK_CONSTANTS,
    MODELS,
    ROBOT,
    TRAJECTORY,
    check_buffers,
    check_results,
    fused_kernel,
    replan_cap,
)

__all__ = ["BAIL", "DONE", "cycle_kernel"]

DONE, BAIL = 0, 1
"""Return codes: the loop ran to its end / a check ended in a state a classification cannot
produce (unproved entries without link energies: the caller faults the cycle)."""


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
            planning_kernels, trajectory_kernels, shielded_kernels, contact_kernels,
            pfl_kernels, pfl_link_states, pfl_fused_kernels,
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
        Returns ``(code, plan, check)``: the last replan's slab
        (:func:`~sara_app.robot.shielded_kernels.plan_views`; empty when there was none) and
        the last check's ``(slabs, state)`` (see
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
            ok, status, robot_c, trajectory_c, plan_c, _ = plan_at_cap(
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
