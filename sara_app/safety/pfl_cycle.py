"""A PFL shield cycle's checks and replans for one person in one compiled call.

``PflShield._plan_and_verify`` plans the trajectory at the held cap, checks it, and while a check
fails and a slower plan can fix it, plans again at the candidate cap and checks that (at most
``1 + max_replans`` checks and ``max_models`` model evaluations). With the fused check
(:mod:`sara_app.safety.pfl_fused`) each check is one compiled call, but the replans, the opening
of each check and the decisions between them were still Python: ~200 us of a two-check cycle.
:class:`CompiledCycle` runs everything after the first plan in one kernel
(:func:`~sara_app.safety.pfl_cycle_kernel.cycle_kernel`): the same kernels on the same numbers
and the same decisions, so the same bits as the Python loop (kept as the reference and for
what the kernel leaves to it: several people, the arm model, a follower that falls back on its
held failsafe or cannot plan, a rejected trajectory; tested cycle by cycle in
``tests/test_pfl_fused.py``, the hand-over in ``tests/test_pfl_cycle.py``). Python builds the
step, the trajectory and the verdict objects only for the last check.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from sara_app.errors import ParameterError
from sara_app.robot.failsafe import BOUND_PAD
from sara_app.robot.occupancy import RobotOccupancy
from sara_app.robot.shielded import ShieldedTrajectory, from_samples
from sara_app.robot.trajectory import PathFollower
from sara_app.safety.pfl import PflResult
from sara_app.safety.pfl_cycle_kernel import DONE, cycle_kernel, plan_views
from sara_app.safety.pfl_fused import KINDS, FusedChecks, result_of
from sara_app.safety.shield import Humans

__all__ = ["CompiledCycle", "CycleOutcome"]

_NAMES = {code: name for name, code in KINDS.items()}


class CycleOutcome(NamedTuple):
    """The last checked trajectory (``traj``, its capsules ``ends (K, L, 2, 3)``, ``radius (K,
    L)``) and its verdict ``result``; ``cap`` its path-speed cap, ``next_cap`` the cap the
    failures set for the next cycle (NaN: none failed), ``checks``, ``models`` (of the last
    check), ``allowed`` (the speed at which a verified check's contacts reach their
    thresholds), ``evaluations`` (model evaluations over all checks)."""

    traj: ShieldedTrajectory
    ends: np.ndarray
    radius: np.ndarray
    result: PflResult
    cap: float
    next_cap: float
    checks: int
    models: int
    allowed: float
    evaluations: int


class CompiledCycle:
    """The replan loop of one shield (its fused checks, robot occupancy with the tracking
    margin ``margin_m (L,)``, control period ``dt_s``, longest failsafe interval
    ``max_interval_s``)."""

    def __init__(
        self,
        fused: FusedChecks,
        occupancy: RobotOccupancy,
        margin_m: np.ndarray,
        dt_s: float,
        max_interval_s: float,
    ) -> None:
        if not (np.isfinite(max_interval_s) and max_interval_s > 0 and dt_s > 0):
            raise ParameterError(
                f"dt_s = {dt_s}, max_interval_s = {max_interval_s}; expected times > 0"
            )
        self.fused = fused
        q_index, N, parents, link_joint, ends_joint, _axes, T0 = occupancy.kernel_arrays()
        lipschitz, radius0 = occupancy.interval_arrays()
        margin = np.asarray(margin_m, dtype=np.float64)
        self._occupancy = (q_index, N, parents, link_joint, ends_joint, lipschitz, radius0,
                           np.asarray(T0, dtype=np.float64), margin)  # fmt: skip
        self._sampling = (float(BOUND_PAD), float(max_interval_s))
        self._dt = float(dt_s)
        links = fused.link_states
        self._link_constants = links.kernel_constants()
        self._T0_links = links.base_pose()
        self._info = np.empty(9)
        self._codes = np.empty((2, 0), dtype=np.int64)
        self._synced: tuple[tuple[str, ...], ...] = ((), ())
        """The orders ``_codes`` holds (rebuilt when the lists differ)."""

    def run(
        self,
        follower: PathFollower,
        traj: ShieldedTrajectory,
        ends: np.ndarray,
        radius: np.ndarray,
        hum: Humans,
        control: tuple[float, float, float],
        limits: tuple[int, int],
        orders: tuple[list[str], list[str]],
    ) -> CycleOutcome | None:
        """The loop from ``traj`` (planned at ``control = (cap, c_min, cut)``; ``limits =
        (max_replans, max_models)``; ``orders``: the model orders of first checks and of
        replans, updated in place). None, with nothing changed, where the Python loop must run
        the cycle instead."""
        state = follower.kernel_state(self._dt)
        if state is None:
            return None
        follower_state, planner, path = state
        f = self.fused
        robot, trajectory, human, age = f.validated(traj, ends, radius, hum)
        key = (tuple(orders[0]), tuple(orders[1]))
        if key != self._synced:
            self._codes = np.stack([f.codes(orders[0]), f.codes(orders[1])])
            self._synced = key
        codes = self._codes.copy()  # the kernel's work copy: the lists change only on success
        info = self._info
        code, plan, last = cycle_kernel(
            robot, trajectory, follower_state, planner, path, self._sampling, self._occupancy,
            self._link_constants, self._T0_links, f.kernel_constants(), human, age, control,
            limits, codes, info,
        )  # fmt: skip
        if code != DONE:
            return None
        if info[7]:
            for order, row in zip(orders, codes):
                order[:] = [_NAMES[int(c)] for c in row]
            self._codes = codes
            self._synced = (tuple(orders[0]), tuple(orders[1]))
        checks = int(info[2])
        if checks > 1:  # the last check was a replan: its step and trajectory from the kernel
            K, L, n = last[0][7].shape[0], self._occupancy[5].shape[0], self._occupancy[0].shape[0]
            out, pts, joint, bounds, r_ends, r_radius = plan_views(plan, K, L, n)
            step = follower.step_from_record(out, int(info[6]), self._dt)
            times, s, sd, sdd = pts[0], pts[1], pts[2], pts[3]
            samples = (times, (s, sd, sdd), joint[0], joint[1], joint[3], joint[4], bounds[0],
                       bounds[1], pts[4, : bounds.shape[1]])  # fmt: skip
            traj, ends, radius = from_samples(step, samples), r_ends, r_radius
        return CycleOutcome(
            traj, ends, radius, result_of(*last), float(info[0]), float(info[1]), checks,
            int(info[3]), float(info[5]), int(info[8]),
        )  # fmt: skip
