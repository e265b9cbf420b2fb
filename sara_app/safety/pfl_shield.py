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

Computation: everything after the cycle's first plan (the checks of every person with every
model, the replans and the decisions between them) is one compiled call
(:class:`~sara_app.safety.pfl_cycle.CompiledCycle`), for any number of people. The robot-only
work of a check (link-link and link-box distances, and the link energies and twists, obtained
only when some human set may touch a link: a check without a possible contact verifies whatever
the energies) is shared by the models; each model adds its human-side distances, one
classification and one merge over the intervals still unproved. The dashboard gets the link
energies from :meth:`PflShield.with_energies`, outside the check.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import replace
from typing import Any

import numpy as np

from sara_app.errors import InputError, ParameterError, SaraError
from sara_app.human.reach import HumanReach, part_capsules
from sara_app.robot.energy import G_MARGIN, LinkSamples
from sara_app.robot.model import RobotModel
from sara_app.robot.shielded import ShieldedTrajectory
from sara_app.robot.trajectory import PathFollower
from sara_app.safety.pfl import PflCheck, PflResult
from sara_app.safety.pfl_cycle import CompiledCycle
from sara_app.safety.pfl_link_states import PathLinkStates
from sara_app.safety.pfl_scaling import PflCycle, SpeedScaling
from sara_app.safety.settings import PflSettings, ShieldSettings
from sara_app.safety.shield import CycleResult, Humans, Shield
from sara_app.safety.thresholds import ThresholdSet

__all__ = ["G_MARGIN", "PflCycle", "PflShield", "SpeedScaling", "part_capsules"]


class PflShield(Shield):
    """PFL shield with speed scaling around a :class:`PathFollower` (which it owns).

    ``spec``: the mode's :class:`~sara_app.safety.settings.PflSettings` (thresholds set name,
    threshold edits, contact shape per link, ``min_speed_scale``); ``boxes``: the environment as
    ``T_world_box (B, 4, 4)``, ``half_extents_m (B, 3)``. Raises :class:`ParameterError` for models
    or a robot the compiled check cannot compute
    (:class:`~sara_app.safety.pfl_cycle.CompiledCycle`).
    """

    safety_mode = "pfl"

    def __init__(
        self,
        robot: RobotModel,
        follower: PathFollower,
        reach: HumanReach,
        settings: ShieldSettings | None = None,
        spec: PflSettings | None = None,
        boxes: tuple[np.ndarray, np.ndarray] | None = None,
        scaling: SpeedScaling | None = None,
    ) -> None:
        super().__init__(robot, follower, reach, settings)
        self.spec = spec = spec or PflSettings()
        self.scaling = scaling or SpeedScaling()
        # above_source: the threshold edits above the shipped value (confirmed by the engineer)
        ts, self.above_source = spec.edited_set()
        self.thresholds: ThresholdSet = ts
        self.boxes = _boxes(boxes)
        self._orders = (list(self.settings.models), list(self.settings.models))
        """Model orders of a cycle's first check and of its replans (a slower trajectory is
        often proved by another model): the last one that completed such a check first."""
        self.pfl = PflCheck(robot, reach.skeleton.parts, thresholds=ts,
                            link_shapes=spec.link_shapes,
                            unclampable_pairs=spec.unclampable_pairs)  # fmt: skip
        self._link_states = PathLinkStates(self.pfl.motion, self.pfl.velocity_error)
        s = self.settings
        self.compiled = CompiledCycle(
            self.pfl, self._link_states, reach, s.models, self.boxes, self.occupancy,
            self.tracking_margin_m, s.dt_s, s.max_interval_s,
        )  # fmt: skip
        """The cycle's checks and replans (:mod:`sara_app.safety.pfl_cycle`)."""
        self.cap = math.inf
        """Path-speed cap for the next cycle (rad/s; inf: none)."""
        self._calm = 0
        self.replans = 0
        self.scaled_cycles = 0
        self._warm_up()

    def _warm_up(self) -> None:
        """One compiled cycle at construction (a person standing 1 m in front of the robot's
        base): its first call resolves the argument types (~3 ms), here and not in the first
        control cycle. Leaves the shield's state as it was."""
        J = self.verifier.reach.skeleton.n_joints
        base = np.asarray(self.robot.T_world_base, dtype=float)[:3, 3]
        y = np.broadcast_to(base + [1.0, 0.0, 1.0], (1, J, 3)).copy()
        hum = (y, np.zeros_like(y), np.zeros((1, J)), np.zeros(1), self._no_widening, None)
        sc = self.scaling
        work = (list(self._orders[0]), list(self._orders[1]))
        try:
            traj, ends, radius = self._plan(math.inf)
            self.compiled.run(self.follower, traj, ends, radius, hum, (math.inf, 0.0, sc.cut),
                              (sc.max_replans, sc.model_budget(1)), work)  # fmt: skip
        except SaraError:  # a follower that cannot plan here: the first cycle resolves them
            pass

    def adopt(self, previous: Shield) -> None:
        super().adopt(previous)
        self.cap, self._calm = math.inf, 0

    # -- per-cycle work -------------------------------------------------------------------------

    def _admissible_here(self) -> tuple[float, float]:
        """``(V at the robot's position, largest V of the path)`` (rad/s)."""
        return self.follower.admissible_here()

    def _plan_and_verify(
        self, hum: Humans | None
    ) -> tuple[ShieldedTrajectory, np.ndarray, np.ndarray, bool]:
        """Plan at the held cap, then check and replan in one compiled call
        (:meth:`CompiledCycle.run`); set the next cycle's cap."""
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
        with _inputs_checked():
            out = self.compiled.run(
                self.follower, traj, ends, radius, hum, (cap, c_min, sc.cut),
                (sc.max_replans, sc.model_budget(hum[0].shape[0])), self._orders,
            )  # fmt: skip
        res = out.result
        if out.checks > 1 or not res.safe_all:  # a check failed
            self._calm = 0
        if out.next_cap == out.next_cap:
            self.cap = out.next_cap
        if res.safe_all:
            self._after_success(out.cap, V_top, out.allowed)
        self._record(res, out.cap, V_here, out.checks, out.models, out.evaluations)
        return out.traj, out.ends, out.radius, res.safe_all

    def _record(
        self, res: PflResult, cap: float, V_here: float, checks: int, used: int, evaluations: int
    ) -> None:
        """The cycle's counters and :class:`PflCycle` (``cap``: the last checked trajectory's,
        ``used``: its check's models, ``evaluations``: the cycle's)."""
        self.replans += checks - 1
        scale = min(1.0, cap / V_here) if V_here > 0 else 1.0
        self.scaled_cycles += scale < 1.0
        self._res = PflCycle(res, cap, scale, checks, used, evaluations)

    def _after_success(self, cap: float, V_top: float, allowed: float) -> None:
        """Cap for the next cycle after a verified one at ``cap`` (raise with hysteresis;
        ``allowed``: the speed at which its contacts reach their thresholds)."""
        sc = self.scaling
        self._calm += 1
        self.cap = cap
        if cap == math.inf or self._calm < sc.hold_cycles:
            return
        if allowed == math.inf and sc.free_jump:
            self.cap = math.inf
        elif allowed >= sc.hysteresis * cap:
            new = min(cap * sc.raise_factor, allowed / sc.hysteresis)
            self.cap = math.inf if new >= V_top else max(new, cap)

    def _link_energies(
        self, traj: ShieldedTrajectory
    ) -> tuple[LinkSamples, np.ndarray, np.ndarray]:
        """Link energies, twists and capsules at the samples, the energy bound per interval
        ``(K, L)`` (J) and the Thm VI.2 velocity error ``(K, L)`` (m/s), in one compiled call
        (:class:`~sara_app.safety.pfl_link_states.PathLinkStates`; views of its buffers, valid
        until its next call for a trajectory of as many samples). The energy bound is
        :func:`~sara_app.robot.energy.path_interval_energy_J` with the exact path-speed peak of
        each interval (``traj.sd_max``) and the configuration factor ``q'^T E_i B E_i q'`` at
        its ends (plus ``G_MARGIN``), ``q' = traj.dq`` the path tangent at the samples."""
        return self._link_states.evaluate(traj)

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
