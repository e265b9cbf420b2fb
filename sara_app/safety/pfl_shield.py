"""The PFL shield (Thumm et al. 2024 Sec. V-VII): the robot may touch a person, but never with more
kinetic energy than the contact's class allows; near a person it slows down instead of stopping.

Every cycle (see :class:`~sara_app.safety.shield.Shield` for the commit/brake logic, the fault
handling and the induction, all unchanged): plan the shielded trajectory (one intended step +
its failsafe stop) at the current path-speed cap, build each person's reachable capsules per
interval of that trajectory for each enabled model, and run :class:`~sara_app.safety.pfl.PflCheck`
(eq. 6-7: no contact, or the link's energy below the threshold of the contact's class). The step
is committed only when eq. 7 holds for every interval, link and body part; then the failsafe
the follower holds is the verified one, exactly as in the SSM shield.

Several models ("safe if any model proves it", per entry). The person lies in every sound
model's set. Each rule of the classification is monotone in the human sets: a larger set
touches more links (eq. 8), touches more boxes and links (eq. 10-13), stacks with more body
parts (eq. 39-43: larger virtual body parts, larger summed diameters, so the diameter relaxation
applies less) and therefore gets a class at least as severe and a threshold at least as low;
the link energies do not depend on the human. So an entry ``(interval k, link i, part j)`` that
one model's sets prove safe is safe for the person, whatever the other models say, and eq. 7
holds for the person when every entry is proved by some model. The next model is tried only
over the range of intervals that still has unproved entries. The order does not change what is
proved safe, only how many models a check needs: the model that completed the last successful
check goes first, with one order for a cycle's first check and one for its replans (in closed
loop about one model per check instead of 1.3-1.9; the dashboard's contact classes are the
first model's). A first check that a replan can follow stops after its first model when that
one leaves entries unproved (conservative: fewer proofs; the other models rescued 4 of 1552 such
checks in closed loop) and the next cycle tries another model first; when no replan can follow
it completes with every model. As with SSM, this is sound only when every enabled model is sound
for the person's motion.

Body parts. Models whose capsules are not per body part (R_POS: one ball per limb; the arm
model: one capsule per arm) give each body part the capsule that contains it (both of its
joints, grown by its half thickness, per the model's coverage table ``HumanReach.coverage``;
a capsule is convex, so it then contains the whole body part).

Speed scaling (:mod:`sara_app.safety.pfl_scaling`): near a person the robot slows down along
its path until the check verifies, instead of stopping.

Assumptions beyond the SSM shield's: the link energies are those of the commanded motion (the
controller tracks it; the tracking margin widens the robot's capsules only). The energy over an
interval is bounded with the exact path-speed peak and the configuration factor at the interval
ends plus the measured margin ``G_MARGIN`` (:func:`sara_app.robot.energy.path_interval_energy_J`;
Thumm et al. 2024's eq. 47-48 end values alone miss the speed peak inside the first failsafe
interval).

Speed: the robot-only work of a check (link energies and twists, interval energies, link-link
and link-box distances) is done once per checked trajectory and shared by the models
(:class:`~sara_app.safety.pfl.MergedCheck`); each model adds its human-side distances, one
compiled classification and one compiled merge over the intervals still unproved. The link
energies and twists are obtained only when some human set may touch a link (the broad phase of
the classification): a check without a possible contact verifies whatever the energies, which
is most checks near a person that verify and every check with the person farther away; the
dashboard gets them from :meth:`PflShield.with_energies`, outside the check. For one person
with models among acc / vel / pos / iso13855 (the common case) all of this, from the human sets
to the merged verdict and the speed scaling's candidate, is one compiled call per check
(:mod:`sara_app.safety.pfl_fused`, the same bits as this module's Python composition, which
stays the reference and serves several people and the arm model), and everything after the
cycle's first plan (the checks, the replans and the decisions between them) is one compiled
call per cycle (:mod:`sara_app.safety.pfl_cycle`, the same bits as :meth:`_plan_and_verify`'s
Python loop, which runs what it hands back).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from sara_app.errors import InputError, ParameterError, SaraError
from sara_app.human.reach import MODELS, HumanReach, part_capsules
from sara_app.robot.energy import (
    G_MARGIN,
    LinkSamples,
)
from sara_app.robot.model import RobotModel
from sara_app.robot.shielded import ShieldedTrajectory
from sara_app.robot.trajectory import PathFollower
from sara_app.safety.pfl import MergedCheck, PflCheck, PflResult
from sara_app.safety.pfl_cycle import CompiledCycle
from sara_app.safety.pfl_fused import KINDS, FusedCheck, FusedChecks
from sara_app.safety.pfl_link_states import PathLinkStates
from sara_app.safety.pfl_scaling import PflCycle, SpeedScaling, allowed_speed, candidate
from sara_app.safety.shield import CycleResult, Humans, Shield, ShieldSettings
from sara_app.safety.thresholds import ThresholdSet, load_thresholds

if TYPE_CHECKING:
    from sara_app.scenario import PflSpec


__all__ = ["G_MARGIN", "PflCycle", "PflShield", "SpeedScaling", "part_capsules"]


class PflShield(Shield):
    """PFL shield with speed scaling around a :class:`PathFollower` (which it owns).

    ``spec``: a :class:`sara_app.scenario.PflSpec` (thresholds set name, threshold edits,
    contact shape per link, ``min_speed_scale``); ``boxes``: the environment as ``T_world_box
    (B, 4, 4)``, ``half_extents_m (B, 3)``. The checks are built here, one per number of
    people (1 and 2; more on first use, about 10 ms each).
    """

    safety_mode = "pfl"

    def __init__(
        self,
        robot: RobotModel,
        follower: PathFollower,
        reach: HumanReach,
        settings: ShieldSettings | None = None,
        spec: PflSpec | None = None,
        boxes: tuple[np.ndarray, np.ndarray] | None = None,
        scaling: SpeedScaling | None = None,
    ) -> None:
        super().__init__(robot, follower, reach, settings)
        if spec is None:
            from sara_app.scenario import PflSpec

            spec = PflSpec()
        self.spec = spec
        self.scaling = scaling or SpeedScaling()
        ts = load_thresholds(spec.thresholds)
        self.above_source: list[str] = []
        """Threshold edits above the shipped value (confirmed by the safety engineer)."""
        for o in spec.overrides:
            ts, above = ts.with_energy(o.region, o.contact, o.shape, o.energy_J)
            if above:
                self.above_source.append(f"{o.region}/{o.contact}/{o.shape} = {o.energy_J} J")
        self.thresholds: ThresholdSet = ts
        self.boxes = _boxes(boxes)
        self._part_names = reach.skeleton.parts
        self._part_maps = {m: _map_or_none(part_capsules(reach, m)) for m in self.settings.models}
        """Per model the capsule of each body part (None: capsule ``j`` is body part ``j``)."""
        self._orders = (list(self.settings.models), list(self.settings.models))
        """Model orders of a cycle's first check and of its replans (a slower trajectory is
        often proved by another model): the last one that completed such a check first."""
        self._model_order = self._orders[0]
        """The order the open check tries the models."""
        self._open: tuple[MergedCheck | FusedCheck, Humans, ShieldedTrajectory] | None = None
        self._no_energy = np.zeros(robot.n_links)
        """Link energies at the current state of a check that did not need them (no contact
        possible, so the check verified: they are not used)."""
        self.pfl = PflCheck(robot, self._part_names, thresholds=ts, link_shapes=spec.link_shapes)
        self._link_states = PathLinkStates(self.pfl.motion, self.pfl.velocity_error)
        self.fused: FusedChecks | None = None
        """Checks of one person in one compiled call (:mod:`sara_app.safety.pfl_fused`; the same
        bits as the Python composition, which serves several people, the arm model and a robot
        without the compiled CRBA; None: the Python composition for every check)."""
        if self._link_states.compiled and set(self.settings.models) <= set(KINDS):
            maps = {m: part_capsules(self.verifier.reach, m) for m in self.settings.models}
            self.fused = FusedChecks(self.pfl, self._link_states, self.verifier.reach, maps,
                                     self.boxes)  # fmt: skip
        self.compiled: CompiledCycle | None = None
        """A cycle's checks and replans for one person in one compiled call
        (:mod:`sara_app.safety.pfl_cycle`, the same bits as the Python loop below, which serves
        what it leaves; None: the Python loop for every cycle)."""
        if self.fused is not None:
            s = self.settings
            self.compiled = CompiledCycle(self.fused, self.occupancy, self.tracking_margin_m,
                                          s.dt_s, s.max_interval_s)  # fmt: skip
        self._checks: dict[int, PflCheck] = {1: self.pfl}
        self._check_for(2)  # ~10 ms each: built here, not in a control cycle (more: on use)
        self.cap = math.inf
        """Path-speed cap for the next cycle (rad/s; inf: none)."""
        self._calm = 0
        self.replans = 0
        self.scaled_cycles = 0
        self._warm_up()

    def _warm_up(self) -> None:
        """One fused check and one compiled cycle at construction (a person standing 1 m in
        front of the robot's base): their first call resolves the argument types (~3 ms), here
        and not in the first control cycle. Leaves the shield's state as it was."""
        if self.fused is None:
            return
        J = self.verifier.reach.skeleton.n_joints
        base = np.asarray(self.robot.T_world_base, dtype=float)[:3, 3]
        y = np.broadcast_to(base + [1.0, 0.0, 1.0], (1, J, 3)).copy()
        hum = (y, np.zeros_like(y), np.zeros((1, J)), np.zeros(1), self._no_widening)
        orders = [list(o) for o in self._orders]
        sc = self.scaling
        try:
            traj, ends, radius = self._plan(math.inf)
            self._verify(traj, ends, radius, hum)
            if self.compiled is not None:
                work = (list(orders[0]), list(orders[1]))
                limits = (sc.max_replans, sc.max_models)
                self.compiled.run(self.follower, traj, ends, radius, hum, (math.inf, 0.0, sc.cut),
                                  limits, work)  # fmt: skip
        except SaraError:  # a follower that cannot plan here: the first cycle resolves them
            pass
        for o, saved in zip(self._orders, orders):
            o[:] = saved
        self._open = None

    def adopt(self, previous: Shield) -> None:
        super().adopt(previous)
        self.cap, self._calm = math.inf, 0

    # -- per-cycle work -------------------------------------------------------------------------

    def _check_for(self, H: int) -> PflCheck:
        """The check for ``H`` people (their body parts stacked, multi-body clamping across
        people included), built on first use."""
        c = self._checks.get(H)
        if c is None:
            c = PflCheck(
                self.robot,
                self._part_names * H,
                thresholds=self.thresholds,
                link_shapes=self.spec.link_shapes,
                human_index=np.repeat(np.arange(H), len(self._part_names)),
            )
            self._checks[H] = c
        return c

    def _admissible_here(self) -> tuple[float, float]:
        """``(V at the robot's position, largest V of the path)`` (rad/s)."""
        return self.follower.admissible_here()

    def _plan(self, cap: float) -> tuple[ShieldedTrajectory, np.ndarray, np.ndarray]:
        f = self.follower
        old = f.speed_cap
        f.speed_cap = cap
        try:
            return self._shielded()
        finally:
            f.speed_cap = old

    def _plan_and_verify(
        self, hum: Humans | None
    ) -> tuple[ShieldedTrajectory, np.ndarray, np.ndarray, bool]:
        V_here, V_top = self._admissible_here()
        if hum is None:  # nobody in the cell: full speed
            self.cap, self._calm = math.inf, self.scaling.hold_cycles
            traj, ends, radius = self._plan(math.inf)
            self._res = PflCycle(None, math.inf, 1.0, 0, 0)
            return traj, ends, radius, True
        sc = self.scaling
        c_min = self.spec.min_speed_scale * V_here
        cap = max(self.cap, c_min)
        traj, ends, radius = self._plan(cap)
        if self.compiled is not None and self.fused is not None and hum[0].shape[0] == 1:
            done = self._compiled_cycle(traj, ends, radius, hum, cap, c_min, V_here, V_top)
            if done is not None:
                return done
        checks = 0
        left = sc.max_models  # model evaluations left in this cycle
        while True:
            self._model_order = self._orders[checks > 0]
            # a replan can follow: a failing check stops after its first model when the replan
            # will follow (the others rescued 4 of 1552 failed first checks in closed loop, the
            # replan checks them all); else every model counts
            lazy = checks < sc.max_replans and left > 1
            replan = (cap, c_min) if lazy else None
            res, used, E0 = self._verify(traj, ends, radius, hum, limit=left, replan=replan)
            left -= used
            checks += 1
            if not res.safe_all:
                cand, fixable = self._next_cap(res, traj, E0, cap)
                if lazy and used == 1 and len(self._model_order) > 1:
                    # it stopped for the replan (with left > 1 it goes on otherwise): next
                    # time another model first
                    self._model_order.append(self._model_order.pop(0))
            if res.safe_all:
                self._after_success(res, traj, cap, c_min, V_top)
                break
            self._calm = 0
            if not (cand >= c_min):  # NaN too
                self.cap = c_min
                break
            self.cap = cand
            if not fixable or checks > sc.max_replans or left < 1:
                break
            cap = cand
            traj, ends, radius = self._plan(cap)
        self._record(res, cap, V_here, checks, used, sc.max_models - left)
        return traj, ends, radius, res.safe_all

    def _record(
        self, res: PflResult, cap: float, V_here: float, checks: int, used: int, evaluations: int
    ) -> None:
        """The cycle's counters and :class:`PflCycle` (``cap``: the last checked trajectory's,
        ``used``: its check's models, ``evaluations``: the cycle's)."""
        self.replans += checks - 1
        scale = min(1.0, cap / V_here) if V_here > 0 else 1.0
        self.scaled_cycles += scale < 1.0
        self._res = PflCycle(res, cap, scale, checks, used, evaluations)

    def _compiled_cycle(
        self,
        traj: ShieldedTrajectory,
        ends: np.ndarray,
        radius: np.ndarray,
        hum: Humans,
        cap: float,
        c_min: float,
        V_here: float,
        V_top: float,
    ) -> tuple[ShieldedTrajectory, np.ndarray, np.ndarray, bool] | None:
        """The loop of :meth:`_plan_and_verify` after its first plan ``traj`` (at ``cap``, its
        capsules ``ends, radius``) in one compiled call (:class:`CompiledCycle`); None where it
        leaves the cycle to the Python loop (nothing changed)."""
        sc = self.scaling
        with _inputs_checked():
            out = cast(CompiledCycle, self.compiled).run(
                self.follower, traj, ends, radius, hum, (cap, c_min, sc.cut),
                (sc.max_replans, sc.max_models), self._orders,
            )  # fmt: skip
        if out is None:
            return None
        res = out.result
        self._open = None
        self._model_order = self._orders[out.checks > 1]
        if out.checks > 1 or not res.safe_all:  # a check failed
            self._calm = 0
        if out.next_cap == out.next_cap:
            self.cap = out.next_cap
        if res.safe_all:
            self._after_success(res, out.traj, out.cap, c_min, V_top, out.allowed)
        self._record(res, out.cap, V_here, out.checks, out.models, out.evaluations)
        return out.traj, out.ends, out.radius, res.safe_all

    def _next_cap(
        self, res: PflResult, traj: ShieldedTrajectory, E0: np.ndarray, cap: float
    ) -> tuple[float, bool]:
        """After a failed check at ``cap``: the replan's cap (``cut`` times the candidate, and at
        most ``cut`` times the current cap and top speed) and whether a replan can fix it."""
        check = self._open[0] if self._open is not None else None
        if isinstance(check, FusedCheck):  # computed by its kernel, from the same result
            cand, fixable = check.candidate()
        else:
            cand, fixable = candidate(res, traj, E0)
        cut = self.scaling.cut
        return min(cut * cand, cut * min(cap, float(traj.sd.max()))), fixable

    def _after_success(
        self,
        res: PflResult,
        traj: ShieldedTrajectory,
        cap: float,
        c_min: float,
        V_top: float,
        allowed: float | None = None,
    ) -> None:
        """Cap for the next cycle after a verified one (raise with hysteresis; ``allowed``:
        the speed at which its contacts reach their thresholds, if already known)."""
        sc = self.scaling
        self._calm += 1
        self.cap = cap
        if cap == math.inf or self._calm < sc.hold_cycles:
            return
        if allowed is None:
            check = self._open[0] if self._open is not None else None
            if isinstance(check, FusedCheck):
                allowed = check.allowed_speed()
            else:
                allowed = allowed_speed(res, traj)
        if allowed == math.inf and sc.free_jump:
            self.cap = math.inf
        elif allowed >= sc.hysteresis * cap:
            new = min(cap * sc.raise_factor, allowed / sc.hysteresis)
            self.cap = math.inf if new >= V_top else max(new, cap)

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
        """Eq. 6-7 for the trajectory against every person, models merged per entry; also the
        number of models evaluated and the link energies at the current state ``(L,)`` (a view,
        valid until the next check; zeros when no contact was possible, then unused).
        ``first_only``: stop after the first model even if it leaves entries unproved
        (:meth:`_finish_check` adds the others; a failed result is then conservative);
        ``limit``: evaluate at most this many models (``>= 1``; None: no limit); ``replan =
        (cap, c_min)``: stop after a failing first model when a replan will follow (the
        check at path-speed cap ``cap`` is fixable and :meth:`_next_cap` is at least ``c_min``),
        else go on with the others."""
        with _inputs_checked():
            if self.fused is not None and hum[0].shape[0] == 1:
                self._open = (self.fused.open(traj, ends, radius, hum), hum, traj)
                return self._add_models(first_only, limit, replan)
            pfl = self._check_for(hum[0].shape[0])
            dt = traj.times[1:] - traj.times[:-1]

            def link_state() -> tuple[LinkSamples, np.ndarray, np.ndarray]:
                smp, energy, eps = self._link_energies(traj)
                return smp, eps, energy

            # the link energies and twists only when some human set may touch a link
            check = pfl.merged_deferred(ends, radius, dt, *self.boxes, link_state)
            self._open = (check, hum, traj)
            return self._add_models(first_only, limit, replan)

    def _finish_check(self, limit: int | None = None) -> tuple[PflResult, int, np.ndarray]:
        """The last :meth:`_verify` with every model (after ``first_only``), at most ``limit``
        more."""
        with _inputs_checked():
            return self._add_models(False, limit)

    def _add_models(
        self,
        first_only: bool,
        limit: int | None = None,
        replan: tuple[float, float] | None = None,
    ) -> tuple[PflResult, int, np.ndarray]:
        """Add models to the open check in :attr:`_model_order` until every entry is proved (the
        model that completes it moves to the front) or, with ``first_only``, after one, or after
        ``limit`` more, or (``replan``, see :meth:`_verify`) after a failing first model that a
        replan will follow."""
        if self._open is None:
            raise InputError("no PFL check is open (call _verify first)")
        check, hum, traj = self._open
        order = self._model_order
        stop = len(order) if limit is None else min(len(order), check.models + limit)
        if isinstance(check, FusedCheck):
            codes = cast(FusedChecks, self.fused).codes(order)
            cut = self.scaling.cut
            i = check.add_models(codes, stop, first_only, replan, cut)
            if i > 0:
                order.insert(0, order.pop(i))
            return check.result(), check.models, check.E0
        times = traj.times
        for i in range(check.models, stop):
            lo, hi = check.todo
            h_ends, h_radius = self._human_sets(order[i], hum, times, lo, hi)
            lo, hi = check.add(h_ends, h_radius)
            if lo >= hi:
                if i:
                    order.insert(0, order.pop(i))
                break
            if first_only:
                break
            if replan is not None and check.models == 1:
                E0 = check.samples.energy_J[0] if check.samples is not None else self._no_energy
                cand, fixable = self._next_cap(check.result(), traj, E0, replan[0])
                if fixable and cand >= replan[1]:
                    break
        E0 = check.samples.energy_J[0] if check.samples is not None else self._no_energy
        return check.result(), check.models, E0

    def _link_energies(
        self, traj: ShieldedTrajectory
    ) -> tuple[LinkSamples, np.ndarray, np.ndarray]:
        """Link energies, twists and capsules at the samples, the energy bound per interval
        ``(K, L)`` (J) and the Thm VI.2 velocity error ``(K, L)`` (m/s), in one compiled call
        (:class:`~sara_app.safety.pfl_link_states.PathLinkStates`; views of its buffers, valid
        until its next call for a trajectory of as many samples). The energy bound is
        :func:`~sara_app.robot.energy.path_interval_energy_J` with the exact path-speed peak of
        each interval (``traj.sd_max``) and the configuration factor ``q'^T E_i B E_i q'`` at
        its ends (plus ``G_MARGIN``), ``q' = traj.dq`` the path tangent at the samples; the
        error bound is from the trajectory's joint speed and acceleration bounds per interval
        and the joint jerk limits."""
        return self._link_states.evaluate(traj)

    def _human_sets(
        self, model: str, hum: Humans, times: np.ndarray, lo: int, hi: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Every person's capsule per body part for intervals ``lo:hi``: ``(k|1, H P, 2, 3)``,
        ``(k|1, H P)`` (a leading 1: the same on every interval); the sets grow from each
        measurement time (age) to the interval ends."""
        y, v, dv, age, widen = hum
        H, P, k = y.shape[0], len(self._part_names), hi - lo
        pm = self._part_maps[model]
        row = MODELS.index(model)
        if H == 1:  # the common case: no broadcast copies
            occ = self.verifier.occupancy(
                model, y, v, dv, times[lo:hi] + age[0], times[lo + 1 : hi + 1] + age[0]
            )
            if widen[0, row].any():  # a widened person: new arrays (their set grows)
                r = occ.radius[0] if pm is None else occ.radius[0][:, pm]
                return (occ.ends[0] if pm is None else occ.ends[0][:, pm]), r + widen[0, row]
            if pm is None:  # a capsule per body part: the model's buffers (views), no copy
                return occ.ends[0], occ.radius[0]
            return occ.ends[0][:, pm], occ.radius[0][:, pm]
        h_ends = np.empty((k, H * P, 2, 3))
        h_radius = np.empty((k, H * P))
        for h in range(H):
            ts = times[lo:hi] + age[h]
            te = times[lo + 1 : hi + 1] + age[h]
            occ = self.verifier.occupancy(model, y[h : h + 1], v[h : h + 1], dv[h : h + 1], ts, te)
            C = occ.radius.shape[-1]
            e = np.broadcast_to(occ.ends[0], (k, C, 2, 3))
            r = np.broadcast_to(occ.radius[0], (k, C))
            h_ends[:, h * P : (h + 1) * P] = e if pm is None else e[:, pm]
            h_radius[:, h * P : (h + 1) * P] = (r if pm is None else r[:, pm]) + widen[h, row]
        return h_ends, h_radius

    def with_energies(self, result: PflResult, traj: ShieldedTrajectory) -> PflResult:
        """``result`` with the link energies over ``traj``, the trajectory it checked, where the
        check skipped them (no link could touch anybody): for the display, outside the
        check. Raises :class:`InputError` when ``traj`` does not match the result."""
        if result.energy_known:
            return result
        with _inputs_checked():
            E = self._link_energies(traj)[1].copy()  # the result keeps it: not a buffer view
        if E.shape != result.energy_J.shape:
            raise InputError(
                f"trajectory energies {E.shape} do not match the PFL result {result.energy_J.shape}"
            )
        margin = result.threshold_J - E[:, :, None]
        return replace(result, energy_J=E, margin_J=margin, energy_known=True)

    def _annotate(self, out: CycleResult, res: Any) -> None:
        if not isinstance(res, PflCycle):
            return
        out.pfl = res.result
        out.speed_scale = res.speed_scale
        out.intervened = out.intervened or res.speed_scale < 1.0


# --- helpers -----------------------------------------------------------------------------------


@contextmanager
def _inputs_checked() -> Iterator[None]:
    """A numeric failure inside a PFL check is an input error of the cycle (a fault)."""
    try:
        yield
    except (ValueError, ArithmeticError, IndexError, np.linalg.LinAlgError) as e:
        raise InputError(f"PFL check failed on its inputs: {e}") from e


def _map_or_none(index: np.ndarray) -> np.ndarray | None:
    """None for the identity map (no gather needed), else ``index``."""
    return None if np.array_equal(index, np.arange(index.shape[0])) else index


def _boxes(boxes: tuple[np.ndarray, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray]:
    if boxes is None:
        return np.zeros((0, 4, 4)), np.zeros((0, 3))
    T = np.asarray(boxes[0], dtype=float)
    half = np.asarray(boxes[1], dtype=float)
    B = T.shape[0] if T.ndim == 3 else -1
    if T.shape != (B, 4, 4) or half.shape != (B, 3):
        raise ParameterError(
            f"environment boxes {T.shape}, {half.shape}; expected (B, 4, 4) and (B, 3)"
        )
    if not (np.all(np.isfinite(T)) and np.all(np.isfinite(half)) and np.all(half > 0)):
        raise ParameterError("environment boxes must be finite with half extents > 0 (m)")
    return T, half
