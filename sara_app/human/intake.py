"""One person's measurements on their way to the shield: the tracking quality gate, the velocity
estimator and the conformance monitor, in that order (one path for the live worker and the
simulation).

A frame goes through the gate (:mod:`sara_app.human.gate`): held joints are replaced by their
last trusted position and widened; the estimator (:mod:`sara_app.human.velocity`) uses trusted
frames only; the monitor (:mod:`sara_app.human.conformance`) checks the trusted motion against
the parameter set and faults the person while it does not hold. A frame with a joint held too
long is refused (the caller counts it; the person ages; the estimator keeps its stamp with
every joint distrusted).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sara_app.errors import InputError
from sara_app.human.conformance import Monitor, Violation
from sara_app.human.gate import FLAGS, Gate, GateResult, why
from sara_app.human.gate_kernels import repeated_frame
from sara_app.human.params import ReachParams
from sara_app.human.recording import Recording
from sara_app.human.skeleton import FULL_JOINTS
from sara_app.human.stated_velocity import reconcile
from sara_app.human.tracking_settings import DEFAULT_INTAKE, IntakeSettings
from sara_app.human.velocity import VelocityEstimator
from sara_app.kernel_types import as_f8, entry

Displacement = tuple[np.ndarray, float] | None
"""A monitor's displacement bound: ``(disp_m (J, N), disp_step_s)`` of the parameter set
(:class:`~sara_app.human.params.DisplacementBound`); None: none."""

_REPEATED = entry(repeated_frame)
"""Without numba's dispatcher: ``Intake._repeated`` checks the shapes and dtypes."""

SETTLE_S = 0.3
"""How long a person must have been measured standing at one place before their sets there are
at least as conservative as a fresh person's, whatever came before (jumps, swaps, freezes, gaps:
the history property, ``tests/test_ingest_history.py``). It is the velocity estimator's reach
(8 frames: 0.27 s at 30 Hz) with margin: before it, a fresh person's first frames have no
velocity estimate (the acceleration models are unusable for them) while a person who walked
there has a sound one; a held joint's set meanwhile encloses its history and its measurement."""


@dataclass(frozen=True)
class TrackingNow:
    """A person's tracking as it stands: ``held`` ``(joint, flag, since_s)`` for every joint
    the gate holds now (its last trusted position, grown by the reach since ``since_s``;
    ``flag`` why), ``last_flag`` ``(joint, flag, stamp_s)`` the newest flag of the gate or
    the conformance monitor (None: never flagged)."""

    held: tuple[tuple[str, str, float], ...]
    last_flag: tuple[str, str, float] | None


class Intake:
    """Gate, estimator and monitor of one person (full-skeleton joint order)."""

    def __init__(
        self,
        delta_y_m: float,
        v_max_mps: np.ndarray,
        a_max_mps2: np.ndarray,
        settings: IntakeSettings = DEFAULT_INTAKE,
        pelvis_rise_mps: float = np.inf,
        displacement: Displacement = None,
    ) -> None:
        J = len(v_max_mps)
        self.gate = Gate(np.asarray(v_max_mps, float), settings.gate)
        self.estimator = VelocityEstimator(J, delta_y_m, a_max_mps2)
        disp_m, disp_step_s = _table(displacement, J)
        self.monitor = Monitor(FULL_JOINTS[:J], v_max_mps, a_max_mps2, settings.recover_s,
                               _pelvis_rise(J, pelvis_rise_mps), disp_m, disp_step_s)  # fmt: skip
        self.stale_after_s = settings.stale_after_s
        self.refusal: str | None = None
        """Why the last frame :meth:`take` returned None for: ``tracking_inconsistent`` or
        ``repeated`` (the contract's reasons)."""
        self._raw = np.full((J, 3), np.nan)  # the last frame as measured
        self._none_missing = np.zeros(J, dtype=np.bool_)
        self._none_trusted = np.zeros(J, dtype=np.bool_)
        self._raw_since_s = -np.inf  # stamp of the first frame with those values
        self.newest_s = -np.inf  # the newest stamp taken, repeated or not
        self.repeats = 0

    def retune(
        self, delta_y_m: float, v_max_mps: np.ndarray, a_max_mps2: np.ndarray,
        settings: IntakeSettings, pelvis_rise_mps: float = np.inf,
        displacement: Displacement = None,
    ) -> None:  # fmt: skip
        """New parameters (a scenario edit): what was learned stays, velocity bounds restart."""
        self.gate.retune(v_max_mps, settings.gate)
        self.estimator.retune(delta_y_m, a_max_mps2)
        J = len(v_max_mps)
        self.monitor.retune(v_max_mps, a_max_mps2, settings.recover_s,
                            _pelvis_rise(J, pelvis_rise_mps), *_table(displacement, J))  # fmt: skip
        self.stale_after_s = settings.stale_after_s

    def take(
        self, t_s: float, y: np.ndarray, delta_y_m: float, n_measured: int,
        missing: np.ndarray | None = None,
    ) -> tuple[GateResult, np.ndarray, np.ndarray] | None:  # fmt: skip
        """Gate, estimate and monitor one frame ``y (J, 3)``; returns the gate's result and the
        velocity ``(J, 3)`` with its bound ``(J,)`` (arrays owned by the intake), or None when
        the frame is not taken (``refusal`` says why). ``missing (J,)``: joints the tracker did
        not measure (held by the gate). A stamp that does not advance raises InputError
        (nothing is changed then).

        A frame whose measured joints all repeat the previous frame's bit-exactly (the
        stale-tracker rule on) is no new measurement: nothing is changed, the person keeps the
        stamp of the first frame with those values and ages (``repeated``); past
        ``stale_after_s`` the person is a fault (:meth:`fault`)."""
        self.refusal = None
        if self.estimator.delta_y_m != delta_y_m:  # its velocity error bound grows with it
            self.estimator.retune(delta_y_m, self.estimator.a_max)
        if not t_s > self.newest_s:  # newest_s is at least the estimator's newest stamp
            raise InputError(f"skeleton time stamp {t_s} does not advance past {self.newest_s}")
        self.newest_s = t_s
        if self._repeated(t_s, y, n_measured, missing):
            self.repeats += 1
            self.refusal = "repeated"
            return None
        g = self.gate.check(t_s, y, delta_y_m, n_measured, missing)
        # The monitor sees refused frames too: a measurement that still disagrees with the
        # history keeps the person's fault alive (recover_s counts from the last one).
        # the pelvis's rise bounds unmeasured legs (sara_app.human.legs): checked where they are
        self.monitor.observe(t_s, g.y, g.trusted, delta_y_m, g.jump_speed_mps,
                             rise=n_measured < len(y))  # fmt: skip
        if g.refused:
            self.refusal = "tracking_inconsistent"
            # its stamp enters the estimator with every joint distrusted: later frames then
            # have the lags a fresh person's frames give them, and one that falls on this frame
            # has no estimate. Skipped, it let later frames reach across it to older ones, a
            # differently centred estimate that cleared a torso where a fresh person's at the
            # same place did not (tests/test_ingest_history.py, found in CI 2026-12-05)
            self.estimator.update(t_s, g.y, self._none_trusted)
            return None
        v, dv = self.estimator.update(t_s, g.y, g.trusted)
        return g, v, dv

    def stated(
        self, t_s: float, v_s: np.ndarray, dv_s: np.ndarray, v_e: np.ndarray, dv_e: np.ndarray,
        trust: bool,
    ) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """The velocity ``(J, 3)`` and bound ``(J,)`` to use for the frame ``t_s`` just taken,
        from a tracker's stated ``v_s``, ``dv_s`` and the estimate ``v_e``, ``dv_e`` that
        :meth:`take` returned: with ``trust``, the ball around both
        (:func:`~sara_app.human.stated_velocity.reconcile`), else the estimate's. Either way a
        joint whose stated velocity the positions contradict is the monitor's violation."""
        v, dv, contradicted, gap = reconcile(v_s, dv_s, v_e, dv_e)
        if contradicted.any():
            self.monitor.contradicted(t_s, contradicted, gap, dv_s + dv_e)
        return (v, dv) if trust else (v_e.copy(), dv_e.copy())

    def _repeated(
        self, t_s: float, y: np.ndarray, n_measured: int, missing: np.ndarray | None
    ) -> bool:
        """Whether ``y``'s measured joints repeat the last frame's exactly (rule on); keeps the
        last frame and when its values first came."""
        J = self._raw.shape[0]
        y = as_f8(y)
        lost = self._none_missing if missing is None else np.asarray(missing, dtype=np.bool_)
        if y.shape != (J, 3) or lost.shape != (J,):
            raise InputError(f"frame {y.shape}, missing {lost.shape}; expected ({J}, 3), ({J},)")
        same = bool(_REPEATED(y, self._raw, int(n_measured), lost))  # raw := y unless same
        if not same:
            self._raw_since_s = t_s
        return same and self.stale_after_s is not None

    @property
    def stale_s(self) -> float:
        """How long the newest frame's values have repeated (0: they changed last frame)."""
        return self.newest_s - self._raw_since_s if self.stale_after_s is not None else 0.0

    def fault(self, human_id: str) -> str | None:
        """The person's fault: a stale tracker, or motion beyond the bounds; else None."""
        if self.stale_after_s is not None and self.stale_s > self.stale_after_s:
            return (
                f"human {human_id!r}: skeleton repeated bit-exactly for {self.stale_s:.2f} s > "
                f"{self.stale_after_s} s (a stale tracker): aging as unseen"
            )
        return self.monitor.fault(human_id)

    def now(self) -> TrackingNow | None:
        """The person's tracking now; None when nothing was ever flagged."""
        g, m = self.gate, self.monitor
        held = (
            ()
            if g.out.trusted.all()
            else tuple(  # all trusted: the common case, one call
                (m.joints[j], FLAGS[why(g.out.flags[j])], float(g.since_s[j]))
                for j in np.flatnonzero(~g.out.trusted & np.isfinite(g.since_s))
            )
        )
        last = None
        if g.last_flag is not None:
            j, k, t_s = g.last_flag
            last = (m.joints[j], FLAGS[k], t_s)
        if m.last and (last is None or m.last_violation_s >= last[2]):
            last = (m.last[0].joint, m.last[0].quantity, m.last_violation_s)
        return None if not held and last is None else TrackingNow(held, last)

    def counts(self) -> dict[str, int]:
        """Flags of the gate and the monitor since the intake was built, and frames repeated."""
        return {**self.gate.counts, **self.monitor.counts, "repeated": self.repeats}


@dataclass
class Screening:
    """A recording through one person's intake: ``held (T, J)`` joints the gate distrusted,
    ``flags (T, J, len(FLAGS))``, ``refused (T,)`` frames refused, ``violations`` the monitor's
    (every one, in order) and ``counts`` as :meth:`Intake.counts`."""

    held: np.ndarray
    flags: np.ndarray
    refused: np.ndarray
    violations: list[Violation]
    counts: dict[str, int]
    peak_speed_mps: np.ndarray
    """``(J,)`` the largest speed / acceleration the trusted motion needed (the monitor's)."""
    peak_acc_mps2: np.ndarray
    faulted: np.ndarray
    """``(T,)`` frames after which the person was a fault (:meth:`Intake.fault`: the monitor or
    a stale tracker): a live cell would not have moved on them."""

    @property
    def glitched(self) -> np.ndarray:
        """``(T, J)`` joint-frames the gate blamed for a glitch (bone, frozen, missing): not a
        measurement of the person (a joint that only jumped is one, of motion beyond the set)."""
        cols = [FLAGS.index(f) for f in ("bone", "frozen", "missing")]
        return np.asarray(self.flags[:, :, cols].any(axis=2))

    def summary(self, joints: tuple[str, ...]) -> list[str]:
        """Lines naming what was flagged, per flag and joint with its first time."""
        out = []
        for k, name in enumerate(FLAGS):
            hit = self.flags[:, :, k]
            for j in np.flatnonzero(hit.any(axis=0)):
                out.append(f"{name} {joints[j]}: {int(hit[:, j].sum())} frames")
        by: dict[tuple[str, str], list[Violation]] = {}
        for v in self.violations:
            by.setdefault((v.joint, v.quantity), []).append(v)
        for (joint, q), vs in by.items():
            worst = max(vs, key=lambda v: v.value)
            out.append(
                f"beyond {q} bound {joint}: {len(vs)} frames, worst {worst.value:.2f} > "
                f"{worst.bound:.2f} at t={worst.t_s:.3f}s"
            )
        return out


def screen(
    times_s: np.ndarray,
    y: np.ndarray,
    delta_y_m: float,
    v_max_mps: np.ndarray,
    a_max_mps2: np.ndarray,
    settings: IntakeSettings | None = None,
    missing: np.ndarray | None = None,
    displacement: Displacement = None,
) -> Screening:
    """Every frame ``y (T, J, 3)`` through a fresh intake (:meth:`Intake.take`, as a live cell
    takes it: a refused frame does not feed the estimator); ``missing (T, J)``: joint-frames the
    tracker did not measure; ``displacement``: the monitor's displacement bound."""
    intake = Intake(delta_y_m, v_max_mps, a_max_mps2, settings or IntakeSettings(),
                    displacement=displacement)  # fmt: skip
    T, J = y.shape[:2]
    held = np.zeros((T, J), bool)
    flags = np.zeros((T, J, len(FLAGS)), bool)
    refused = np.zeros(T, bool)
    faulted = np.zeros(T, bool)
    violations: list[Violation] = []
    m = intake.monitor
    for i in range(T):
        t = float(times_s[i])
        intake.take(t, y[i], delta_y_m, J, None if missing is None else missing[i])
        g = intake.gate.out  # this frame's gate result, refused or not
        held[i], flags[i], refused[i] = ~g.trusted, g.flags, g.refused
        faulted[i] = intake.fault("") is not None
        if m.last_violation_s == t:  # the monitor found violations in this frame
            violations += m.last
    return Screening(held, flags, refused, violations, intake.counts(), m.peak_speed_mps,
                     m.peak_acc_mps2, faulted)  # fmt: skip


def screen_recording(params: ReachParams, rec: Recording) -> Screening:
    """``rec`` through a fresh intake under ``params`` (its noise bound and the bounds of the
    recording's joints): what a live cell's gate and monitor make of that person."""
    J = rec.positions_m.shape[1]
    return screen(rec.times_s, rec.positions_m, params.delta_y_m, params.v_max_mps[:J],
                  params.a_max_mps2[:J], displacement=displacement_of(params))  # fmt: skip


def displacement_of(params: ReachParams) -> Displacement:
    """The monitor's displacement bound of ``params`` (None where the set has none)."""
    if params.disp_max_m.shape[1] == 0:
        return None
    return params.disp_max_m, params.disp_step_s


def _table(displacement: Displacement, n_joints: int) -> tuple[np.ndarray, float]:
    """The monitor's ``(disp_m (J, N), disp_step_s)``: the first ``n_joints`` rows."""
    if displacement is None:
        return np.zeros((n_joints, 0)), 1.0
    return displacement[0][:n_joints], displacement[1]


def _pelvis_rise(n_joints: int, pelvis_rise_mps: float) -> np.ndarray:
    """``(J,)`` the monitor's upward speed bounds: the pelvis's, none (``inf``) elsewhere."""
    bound = np.full(n_joints, np.inf)
    bound[FULL_JOINTS.index("pelvis")] = pelvis_rise_mps
    return bound
