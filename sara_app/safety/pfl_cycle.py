"""A PFL shield cycle's checks and replans, for any number of people, in one compiled call.

``PflShield._plan_and_verify`` plans the trajectory at the held cap; everything after that is
:func:`~sara_app.safety.pfl_cycle_kernels.cycle_kernel`: the check of that trajectory against
every person (:func:`~sara_app.safety.pfl_fused_kernels.fused_kernel`: per model the people's
capsules over the intervals still unproved, the classification with the link states obtained on
the first possible contact, the per-entry merge), and while a check fails and a slower plan can
fix it, the plan at the candidate cap and its check (at most ``1 + max_replans`` checks and
``max_models`` model evaluations). This is the shield's only check: the Python composition of
the same kernels it is compared with, cycle by cycle, lives in ``tests/pfl_reference.py``.

Several people: their body parts are stacked (person ``h``'s parts at ``h P .. (h+1) P``), each
person's sets grow from that person's own measurement time, and the classification's constants
are those of ``H P`` parts (:func:`rules_for`: two parts of different people never form a safe
pair, so multi-body clamping between people is checked). What the kernel cannot compute is
refused when the shield is built: models other than :data:`KINDS`
(:meth:`CompiledCycle.__init__`), a robot the compiled CRBA does not support
(:class:`~sara_app.robot.energy.LinkMotion`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np

from sara_app.errors import InputError, ParameterError
from sara_app.human.legs import no_bounds
from sara_app.human.reach import MODELS, HumanReach, part_capsules
from sara_app.human.reach_kernels import KINDS  # Pereira's arm model is refused in PFL
from sara_app.robot.failsafe import BOUND_PAD
from sara_app.robot.occupancy import RobotOccupancy
from sara_app.robot.shielded import ShieldedTrajectory, from_samples
from sara_app.robot.shielded_kernels import plan_views
from sara_app.robot.trajectory import PathFollower
from sara_app.safety.contact import ContactResult
from sara_app.safety.pfl import PflCheck, PflResult
from sara_app.safety.pfl_cycle_kernels import DONE, cycle_kernel
from sara_app.safety.pfl_link_states import PathLinkStates
from sara_app.safety.shield import Humans

__all__ = ["KINDS", "CompiledCycle", "CycleOutcome", "result_of", "rules_for"]

_NAMES = {code: name for name, code in KINDS.items()}
_NO_FOLLOWER = (
    (0.0,) * 8,
    (np.zeros((0, 0)), np.zeros((0, 0, 0)), np.zeros((0, 0, 0)), np.zeros(0)),
    (np.zeros(0), np.zeros(0), np.zeros((0, 0, 0)), np.zeros((0, 0)), np.zeros((0, 0)),
     np.zeros((0, 0))),
)  # fmt: skip
"""The kernel's follower arguments where the follower has no path ahead (done): never read,
as such a cycle checks its trajectory without replans (a slower plan of a robot with nothing
ahead is the same plan)."""


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


def rules_for(rules: tuple[np.ndarray, ...], H: int) -> tuple[np.ndarray, ...]:
    """The classification's constants ``(no_pair (L, L), not_safe_h, diameters_m, T_clamp,
    T_free)`` of ``H`` people from one person's (``P`` parts): ``not_safe_h (H P, H P)`` with
    one person's block on the diagonal and every pair of parts of two people not safe (a
    person's arm pressed against another's chest is a clamp, Thumm et al. 2024 Sec. V-B), the
    per-part arrays repeated per person. The same arrays as a :class:`PflCheck` of ``H``
    people's parts with their ``human_index`` (tested)."""
    no_pair, not_safe_1, diameters_1, T_clamp_1, T_free_1 = rules
    P = diameters_1.shape[0]
    not_safe = np.ones((H * P, H * P), dtype=bool)
    for h in range(H):
        not_safe[h * P : (h + 1) * P, h * P : (h + 1) * P] = not_safe_1
    np.fill_diagonal(not_safe, False)
    return (no_pair, not_safe, np.tile(diameters_1, H), np.tile(T_clamp_1, (1, H)),
            np.tile(T_free_1, (1, H)))  # fmt: skip


class CompiledCycle:
    """The checks and replans of one PFL shield: ``pfl`` (one person's thresholds, classifier,
    robot), ``link_states`` (of the same robot), ``reach`` (the
    people's models), ``models`` (names among :data:`KINDS`), the environment ``boxes =
    (T_world_box (B, 4, 4), half_extents_m (B, 3))`` (validated by the caller), the robot
    ``occupancy`` with its tracking margin ``margin_m (L,)``, the control period ``dt_s`` and the
    longest failsafe interval ``max_interval_s``. Raises :class:`ParameterError` for what the
    kernel cannot compute."""

    def __init__(
        self,
        pfl: PflCheck,
        link_states: PathLinkStates,
        reach: HumanReach,
        models: Sequence[str],
        boxes: tuple[np.ndarray, np.ndarray],
        occupancy: RobotOccupancy,
        margin_m: np.ndarray,
        dt_s: float,
        max_interval_s: float,
    ) -> None:
        unknown = [m for m in models if m not in KINDS]
        if unknown:
            raise ParameterError(
                f"model {unknown[0]!r} is not available in PFL mode; valid: {', '.join(KINDS)}"
            )
        if not (np.isfinite(max_interval_s) and max_interval_s > 0 and dt_s > 0):
            raise ParameterError(
                f"dt_s = {dt_s}, max_interval_s = {max_interval_s}; expected times > 0"
            )
        P, J = pfl.n_parts, reach.skeleton.n_joints
        if reach.skeleton.n_parts != P:
            raise ParameterError(
                f"the check has {P} body parts, the reach model {reach.skeleton.n_parts}; "
                "expected one person's parts"
            )
        self._J, self._P, self._L = J, P, pfl.n_links
        maps = np.tile(np.arange(P, dtype=np.int64), (len(KINDS), 1))
        for name in models:
            maps[KINDS[name]] = part_capsules(reach, name)
        # the widening's rows (reach.MODELS order) in the kernel's model-kind order
        self._kind_rows = np.array(
            [MODELS.index(m) for m in sorted(KINDS, key=KINDS.__getitem__)], dtype=np.int64
        )
        self._rules_1 = (*pfl.classifier.kernel_arrays(), pfl.T_clamp, pfl.T_free)
        self._rest = (pfl.classifier.switches(), *reach.kernel_constants(), maps)
        self._models: dict[int, tuple[Any, ...]] = {}
        self._s_radius = np.asarray(pfl.model.radius_m, dtype=np.float64)
        self._boxes = boxes
        self.link_states = link_states
        self._occupancy = occupancy.plan_arrays(margin_m)
        self._sampling = (float(BOUND_PAD), float(max_interval_s))
        self._dt = float(dt_s)
        self._link_constants = link_states.kernel_constants()
        self._T0_links = link_states.base_pose()
        self._info = np.empty(9)
        self._codes = np.empty((2, 0), dtype=np.int64)
        self._synced: tuple[tuple[str, ...], ...] = ((), ())
        """The orders ``_codes`` holds (rebuilt when the lists differ)."""
        self.constants_for(1)
        self.constants_for(2)

    def constants_for(self, H: int) -> tuple[Any, ...]:
        """The check's constants for ``H`` people
        (:data:`~sara_app.safety.pfl_fused_kernels.MODELS`), built on first use (tens of us)."""
        c = self._models.get(H)
        if c is None:
            c = self._models[H] = (rules_for(self._rules_1, H), *self._rest)
        return c

    def validated(
        self, traj: Any, r_ends: np.ndarray, r_radius: np.ndarray, hum: Humans
    ) -> tuple[tuple[np.ndarray, ...], tuple[np.ndarray, ...], tuple[np.ndarray, ...]]:
        """``(robot, trajectory, human)`` as the kernel takes them: the shielded trajectory
        ``traj`` with its robot capsules per interval ``r_ends (K, L, 2, 3)``, ``r_radius (K,
        L)`` and ``H >= 1`` people ``hum = (y, v (H, J, 3), dv (H, J), age (H,), widen (H, M,
        P) or None: none, caps (H, P, 2) or None: none)`` (the widening's rows go to the kernel
        in its model-kind order), as float64; raises :class:`InputError` on other shapes."""
        trajectory = self.link_states.inputs(traj)
        K = trajectory[0].shape[0] - 1
        L, J, P = self._L, self._J, self._P
        r_ends = np.asarray(r_ends, dtype=np.float64)
        r_radius = np.asarray(r_radius, dtype=np.float64)
        y, v, dv, age = (np.asarray(a, dtype=np.float64) for a in hum[:4])
        H = y.shape[0] if y.ndim == 3 else 0
        # None: no widening (Shield._human_arrays' common case)
        widen = np.zeros((H, len(MODELS), P)) if hum[4] is None else np.asarray(hum[4], np.float64)
        caps = no_bounds(H, P) if hum[5] is None else np.asarray(hum[5], np.float64)
        if (
            H < 1 or r_ends.shape != (K, L, 2, 3) or r_radius.shape != (K, L)
            or y.shape != (H, J, 3) or v.shape != (H, J, 3) or dv.shape != (H, J)
            or age.shape != (H,) or widen.shape != (H, len(MODELS), P)
            or caps.shape != (H, P, 2)
        ):  # fmt: skip
            raise InputError(
                f"PFL check inputs r_ends {r_ends.shape}, r_radius {r_radius.shape}, y "
                f"{y.shape}, v {v.shape}, dv {dv.shape}, age {age.shape}, widen {widen.shape}, "
                f"caps {caps.shape}; expected ({K}, {L}, 2, 3), ({K}, {L}), (H, {J}, 3), (H, "
                f"{J}, 3), (H, {J}), (H,), (H, {len(MODELS)}, {P}), (H, {P}, 2) for H >= 1 people"
            )
        robot = (r_ends, r_radius, *self._boxes, self._s_radius)
        widen_kinds = np.ascontiguousarray(widen[:, self._kind_rows])  # rows in KIND order
        return robot, trajectory, (y, v, dv, widen_kinds, age, caps)

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
    ) -> CycleOutcome:
        """The checks from ``traj`` (planned at ``control = (cap, c_min, cut)``; ``limits =
        (max_replans, max_models)``; ``orders``: the model orders of first checks and of
        replans, updated in place). Raises :class:`InputError` on malformed inputs and where
        the kernel ends in a state a classification cannot produce."""
        state = follower.kernel_state(self._dt)
        if state is None:
            state, limits = _NO_FOLLOWER, (0, limits[1])
        follower_state, planner, path = state
        robot, trajectory, human = self.validated(traj, ends, radius, hum)
        key = (tuple(orders[0]), tuple(orders[1]))
        if key != self._synced:
            self._codes = np.stack([_codes(orders[0]), _codes(orders[1])])
            self._synced = key
        codes = self._codes.copy()  # the kernel's work copy: the lists change only on success
        info = self._info
        code, plan, last = cycle_kernel(
            robot, trajectory, follower_state, planner, path, self._sampling, self._occupancy,
            self._link_constants, self._T0_links, self.constants_for(human[0].shape[0]), human,
            control, limits, codes, info,
        )  # fmt: skip
        if code != DONE:
            raise InputError("a PFL check has unproved entries but no link energies")
        if info[7]:
            for order, row in zip(orders, codes):
                order[:] = [_NAMES[int(c)] for c in row]
            self._codes = codes
            self._synced = (tuple(orders[0]), tuple(orders[1]))
        checks = int(info[2])
        if checks > 1:  # the last check was a replan: its step and trajectory from the kernel
            K, L, n = last[0][7].shape[0], self._L, self._occupancy[0].shape[0]
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


def _codes(order: list[str]) -> np.ndarray:
    """The kernel's codes of a model order."""
    return np.array([KINDS[m] for m in order], dtype=np.int64)


def result_of(slabs: tuple[np.ndarray, ...], state: np.ndarray) -> PflResult:
    """The :class:`PflResult` of a check's result arrays and state (the layout of
    :func:`~sara_app.safety.pfl_fused_kernels.check_results`)."""
    b5, f3, i2, stack, diam, safe_k, f2, part = slabs
    contact, contact_s, env, self_, safe = b5
    thr, margin, d_rh = f3
    cls, cls_m = i2
    allowed, E_int = f2
    c = ContactResult(contact, contact_s, env, self_, cls, stack, diam, d_rh)
    merged = bool(state[4])
    return PflResult(
        safe, safe_k, bool(state[5]), cls_m if merged else cls, thr, E_int, margin, c, allowed,
        part, merged or bool(state[3]),
    )  # fmt: skip
