"""The PFL shield's reference: the Python composition of the same kernels that the compiled
cycle (:mod:`sara_app.safety.pfl_cycle`) runs in one call.

Per model: each person's capsules from ``ssm_reference.model_sets`` (the reach models' own
entry points), stacked for several people and classified with a :class:`PflCheck` of ``H``
people's parts built from their ``human_index`` (an independent construction of the
multi-person constants), merged per entry by :class:`MergedCheck`; the replans and decisions
of the shield in a Python loop. Tests compare the production shield with
:class:`ReferencePflShield` cycle by cycle.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import Any, cast

import numpy as np
from ssm_reference import model_sets

from sara_app.errors import InputError, SaraError
from sara_app.human.reach import MODELS, part_capsules
from sara_app.robot.energy import LinkSamples
from sara_app.robot.shielded import ShieldedTrajectory
from sara_app.safety.contact import MotionArrays, RobotSide
from sara_app.safety.pfl import PflCheck, PflResult, _interval_count
from sara_app.safety.pfl_kernels import merge_kernel, speed_kernel, stuck_kernel, summary_kernel
from sara_app.safety.pfl_shield import PflShield, _inputs_checked
from sara_app.safety.shield import Humans


def allowed_speed(res: PflResult, traj: ShieldedTrajectory) -> float:
    """Speed estimate at which the contacts of a verified trajectory reach their thresholds."""
    return float(speed_kernel(False, res.safe, res.cls, res.threshold_J, res.energy_J, traj.sd))


def candidate(res: PflResult, traj: ShieldedTrajectory, E0: np.ndarray) -> tuple[float, bool]:
    """Candidate cap from the violated entries, and whether a slower plan can fix them (no
    violated entry already too energetic at the current state: link energies ``E0 (L,)``)."""
    cand = speed_kernel(True, res.safe, res.cls, res.threshold_J, res.energy_J, traj.sd)
    return float(cand), not stuck_kernel(res.safe, res.threshold_J, E0)


def merged(
    pfl: PflCheck,
    r_ends: np.ndarray,
    r_radius: np.ndarray,
    samples: LinkSamples,
    dt: np.ndarray,
    eps_v: np.ndarray,
    T_world_box: np.ndarray,
    half_extents_m: np.ndarray,
    energy_J: np.ndarray,
) -> MergedCheck:
    """A :class:`MergedCheck` of one trajectory (inputs as in :meth:`PflCheck.check`; ``samples``
    with ``ends, p1_dot, omega`` at the ``K+1`` samples, ``energy_J`` any form of
    :meth:`PflCheck.check`, ``eps_v (K, L)``), to which human sets are added model by model."""
    K = _interval_count(r_radius, dt)
    robot = pfl.classifier.robot_side(
        r_ends, r_radius, samples.ends, pfl._s_radius, samples.p1_dot, samples.omega,
        eps_v, T_world_box, half_extents_m,
    )  # fmt: skip
    return MergedCheck(pfl, robot, pfl._interval_energies(energy_J, K))


def merged_deferred(
    pfl: PflCheck,
    r_ends: np.ndarray,
    r_radius: np.ndarray,
    dt: np.ndarray,
    T_world_box: np.ndarray,
    half_extents_m: np.ndarray,
    link_state: Callable[[], tuple[LinkSamples, np.ndarray, np.ndarray]],
) -> MergedCheck:
    """:func:`merged` with the link states deferred: ``link_state()`` returns ``(samples,
    eps_v, energy_J)`` and is called only when some human set may touch a link (a check
    without a possible contact needs neither the energies nor the twists; its result has
    ``energy_known`` False)."""
    K = _interval_count(r_radius, dt)

    def motion() -> MotionArrays:  # called only after ``check`` below exists
        check = check_ref()
        if check is None:
            raise InputError("the PFL check of these link states no longer exists")
        samples, eps_v, energy_J = link_state()
        check.samples = samples
        check.E_int = pfl._interval_energies(energy_J, K)
        return samples.ends, pfl._s_radius, samples.p1_dot, samples.omega, eps_v

    robot = pfl.classifier.robot_side_deferred(
        r_ends, r_radius, motion, T_world_box, half_extents_m
    )
    check = MergedCheck(pfl, robot, None)
    # a weak reference: check -> robot -> motion -> check would be a reference cycle,
    # garbage only the cyclic collector frees (~35 objects per cycle: collector pauses)
    check_ref = weakref.ref(check)
    return check


def _unproved_range(safe_k: list[bool]) -> tuple[int, int]:
    """``lo:hi`` from the first to the last interval not proved safe (``(K, K)``: none); a
    list, not an array: two numpy calls cost more than this loop over ~10 intervals."""
    K = len(safe_k)
    if all(safe_k):
        return K, K
    return safe_k.index(False), K - safe_k[::-1].index(False)


class MergedCheck:
    """Eq. 6-7 for one trajectory against several human-set models, merged per entry ("safe if
    any model proves it"; the rules are monotone in the human sets, see
    :mod:`sara_app.safety.pfl_shield`). Built by :func:`merged`; :meth:`add` one
    model's sets (the first over every interval, later ones over the range still unproved);
    :meth:`result`: each entry from the first model that proves it safe, an unproved one with
    the highest threshold seen; ``contact`` is the first model's. The robot-only geometry is
    computed once for all models."""

    def __init__(self, pfl: PflCheck, robot: RobotSide, E_int: np.ndarray | None) -> None:
        self.pfl, self.robot = pfl, robot
        self.E_int = E_int
        """Interval energies ``(K, L)``; None while deferred and not needed yet."""
        self.samples: LinkSamples | None = None
        """The link samples of a deferred check once obtained."""
        self.first: PflResult | None = None
        self.models = 0
        self._cls: np.ndarray | None = None
        self._todo = np.empty(2, dtype=np.int64)
        self.todo = (0, robot.K)
        """Interval range ``lo:hi`` with unproved entries (``(K, K)``: every entry proved)."""

    def add(
        self, h_ends: np.ndarray, h_radius: np.ndarray, cap_z: np.ndarray | None = None
    ) -> tuple[int, int]:
        """Classify and merge one model's human capsules for the intervals :attr:`todo` (shapes
        as in :meth:`ContactClassifier.classify_humans`; ``cap_z (K, P)`` the parts' height
        bounds over every interval); returns the new :attr:`todo`."""
        lo, hi = self.todo
        if lo >= hi:
            return self.todo
        caps = None if cap_z is None else cap_z[lo:hi]
        c = self.pfl.classifier.classify_humans(self.robot, h_ends, h_radius, lo, hi, caps)
        self.models += 1
        first = self.first
        if first is None:
            E = self.E_int
            if E is None:  # deferred and no contact possible: the energies do not matter
                E = np.full((self.robot.K, self.robot.L), np.nan)
            first = self.first = self.pfl._verdict(c, E, self.E_int is not None)
            self.todo = _unproved_range(first.safe_interval.tolist())
            return self.todo
        if self._cls is None:
            self._cls = first.cls.copy()
        if self.E_int is None:  # unproved entries of the first model mean possible contact
            raise InputError("a deferred check has unproved entries but no link energies")
        merge_kernel(
            c.stack, c.cls, c.contact, self.pfl.T_clamp, self.pfl.T_free, self.E_int, lo,
            first.safe, self._cls, first.threshold_J, self._todo,
        )  # fmt: skip
        a, b = int(self._todo[0]), int(self._todo[1])
        self.todo = (a, b + 1) if a >= 0 else (self.robot.K, self.robot.K)
        return self.todo

    def result(self) -> PflResult:
        """The merged verdict (fresh arrays); raises :class:`InputError` before any :meth:`add`."""
        f = self.first
        if f is None:
            raise InputError("no human set was checked (add at least one model)")
        if self._cls is None:
            return f
        E = cast(np.ndarray, self.E_int)  # known: a merge needs it (add)
        K, L, P = f.cls.shape
        margin = np.empty((K, L, P))
        safe_k = np.empty(K, dtype=bool)
        allowed = np.empty((K, L))
        part = np.empty((K, L), dtype=np.int64)
        summary_kernel(self._cls, f.threshold_J, E, f.safe, margin, safe_k, allowed,
                        part)  # fmt: skip
        return PflResult(
            f.safe, safe_k, bool(safe_k.all()), self._cls, f.threshold_J, E, margin,
            f.contact, allowed, part,
        )  # fmt: skip


class ReferencePflShield(PflShield):
    """:class:`PflShield` with its cycle composed in Python (see the module notes): the same
    decisions as the compiled cycle, so the same commands, verdicts and caps."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._init_reference()

    def _init_reference(self) -> None:
        reach = self.verifier.reach
        self._part_names = reach.skeleton.parts
        self._part_maps = {m: _map_or_none(part_capsules(reach, m)) for m in self.settings.models}
        self._model_order = self._orders[0]
        self._open: tuple[MergedCheck, Humans, ShieldedTrajectory] | None = None
        self._no_energy = np.zeros(self.robot.n_links)
        self._checks: dict[int, PflCheck] = {1: self.pfl}

    def _check_for(self, H: int) -> PflCheck:
        """The check for ``H`` people: their body parts stacked, with their ``human_index``."""
        c = self._checks.get(H)
        if c is None:
            c = self._checks[H] = PflCheck(
                self.robot, self._part_names * H, thresholds=self.thresholds,
                link_shapes=self.spec.link_shapes,
                human_index=np.repeat(np.arange(H), len(self._part_names)),
            )  # fmt: skip
        return c

    def _plan_and_verify(
        self, hum: Humans | None
    ) -> tuple[ShieldedTrajectory, np.ndarray, np.ndarray, bool]:
        V_here, V_top = self._admissible_here()
        if hum is None:
            return super()._plan_and_verify(hum)
        sc = self.scaling
        # a follower with nothing ahead: no replans (a slower plan is the same plan)
        max_replans = sc.max_replans if self.follower.kernel_state(1e-3) is not None else 0
        c_min = self.spec.min_speed_scale * V_here
        cap = max(self.cap, c_min)
        traj, ends, radius = self._plan(cap)
        checks = 0
        budget = left = sc.model_budget(hum[0].shape[0])
        while True:
            self._model_order = self._orders[checks > 0]
            lazy = checks < max_replans and left > 1
            replan = (cap, c_min) if lazy else None
            res, used, E0 = self._verify(traj, ends, radius, hum, limit=left, replan=replan)
            left -= used
            checks += 1
            if not res.safe_all:
                cand, fixable = self._next_cap(res, traj, E0, cap, checks <= max_replans)
                if lazy and used == 1 and len(self._model_order) > 1:
                    self._model_order.append(self._model_order.pop(0))
            if res.safe_all:
                allowed = allowed_speed(res, traj)
                self._after_success(cap, V_top, allowed)
                break
            self._calm = 0
            if not (cand >= c_min):  # NaN too
                self.cap = c_min
                break
            self.cap = cand
            if not fixable or checks > max_replans or left < 1:
                break
            try:
                planned = self._plan(cand)
            except SaraError:  # no slower plan: the failed check stands
                break
            if planned[0].step.fallback:  # the follower falls back on its held failsafe
                break
            cap = cand
            traj, ends, radius = planned
        self._record(res, cap, V_here, checks, used, budget - left)
        return traj, ends, radius, res.safe_all

    def _next_cap(
        self,
        res: PflResult,
        traj: ShieldedTrajectory,
        E0: np.ndarray,
        cap: float,
        replanning: bool,
    ) -> tuple[float, bool]:
        """A replan's cap (``replanning``: cut x the current speed) or the cap held for the next
        cycle (cut x the energies' candidate, at most that), and whether a replan can help."""
        cand, fixable = candidate(res, traj, E0)
        cut = self.scaling.cut
        top = cut * min(cap, float(traj.sd.max()))
        return (top if replanning else min(cut * cand, top)), fixable

    def _verify(
        self,
        traj: ShieldedTrajectory,
        ends: np.ndarray,
        radius: np.ndarray,
        hum: Humans,
        first_only: bool = False,
        limit: int | None = None,
        replan: tuple[float, float] | None = None,
    ) -> tuple[PflResult, int, np.ndarray]:
        """Eq. 6-7 for the trajectory against every person, models merged per entry; the
        number of models evaluated and the link energies at the current state ``(L,)``."""
        with _inputs_checked():
            pfl = self._check_for(hum[0].shape[0])
            dt = traj.times[1:] - traj.times[:-1]

            def link_state() -> tuple[LinkSamples, np.ndarray, np.ndarray]:
                smp, energy, eps = self._link_energies(traj)
                return smp, eps, energy

            check = merged_deferred(pfl, ends, radius, dt, *self.boxes, link_state)
            self._open = (check, hum, traj)
            return self._add_models(first_only, limit, replan)

    def _finish_check(self, limit: int | None = None) -> tuple[PflResult, int, np.ndarray]:
        with _inputs_checked():
            return self._add_models(False, limit)

    def _add_models(
        self,
        first_only: bool,
        limit: int | None = None,
        replan: tuple[float, float] | None = None,
    ) -> tuple[PflResult, int, np.ndarray]:
        if self._open is None:
            raise InputError("no PFL check is open (call _verify first)")
        check, hum, traj = self._open
        order = self._model_order
        stop = len(order) if limit is None else min(len(order), check.models + limit)
        times = traj.times
        for i in range(check.models, stop):
            lo, hi = check.todo
            h_ends, h_radius = self._human_sets(order[i], hum, times, lo, hi)
            lo, hi = check.add(h_ends, h_radius, _cap_heights(hum, times))
            if lo >= hi:
                if i:
                    order.insert(0, order.pop(i))
                break
            if first_only:
                break
            if replan is not None and check.models == 1:
                E0 = check.samples.energy_J[0] if check.samples is not None else self._no_energy
                cand, fixable = self._next_cap(check.result(), traj, E0, replan[0], True)
                if fixable and cand >= replan[1]:
                    break
        E0 = check.samples.energy_J[0] if check.samples is not None else self._no_energy
        return check.result(), check.models, E0

    def _human_sets(
        self, model: str, hum: Humans, times: np.ndarray, lo: int, hi: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Every person's capsule per body part for intervals ``lo:hi``: ``(k, H P, 2, 3)``,
        ``(k, H P)``; the sets grow from each measurement time (age) to the interval ends."""
        y, v, dv, age, widen = hum[:5]
        if widen is None:  # no widening
            widen = np.zeros((len(y), len(MODELS), len(self._part_names)))
        H, P, k = y.shape[0], len(self._part_names), hi - lo
        pm = self._part_maps[model]
        row = MODELS.index(model)
        h_ends = np.empty((k, H * P, 2, 3))
        h_radius = np.empty((k, H * P))
        for h in range(H):
            ts = times[lo:hi] + age[h]
            te = times[lo + 1 : hi + 1] + age[h]
            occ = model_sets(
                self.verifier.reach, model, y[h : h + 1], v[h : h + 1], dv[h : h + 1], ts, te
            )
            C = occ.radius.shape[-1]
            e = np.broadcast_to(occ.ends[0], (k, C, 2, 3))
            r = np.broadcast_to(occ.radius[0], (k, C))
            h_ends[:, h * P : (h + 1) * P] = e if pm is None else e[:, pm]
            h_radius[:, h * P : (h + 1) * P] = (r if pm is None else r[:, pm]) + widen[h, row]
        return h_ends, h_radius


def _cap_heights(hum: Humans, times: np.ndarray) -> np.ndarray | None:
    """``(K, H P)``: each person's parts' height bounds at each interval's end (None: none)."""
    caps = hum[5]
    if caps is None:
        return None
    tau = times[1:, None] + np.asarray(hum[3])[None, :]  # (K, H)
    z = caps[None, :, :, 0] + caps[None, :, :, 1] * tau[:, :, None]  # (K, H, P)
    return z.reshape(len(times) - 1, -1)


def as_reference(shield: PflShield) -> ReferencePflShield:
    """``shield`` (built by ``build_cell``) turned into its reference, in place."""
    shield.__class__ = ReferencePflShield
    ref = cast(ReferencePflShield, shield)
    ref._init_reference()
    return ref


def _map_or_none(index: np.ndarray) -> np.ndarray | None:
    """None for the identity map (no gather needed), else ``index``."""
    return None if np.array_equal(index, np.arange(index.shape[0])) else index
