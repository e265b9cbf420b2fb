"""One person's measurements on their way to the shield: the tracking quality gate, the velocity
estimator and the conformance monitor, in that order (one path for the live worker and the
simulation).

A frame goes through the gate (:mod:`sara_app.human.gate`): held joints are replaced by their
last trusted position and widened; the estimator (:mod:`sara_app.human.velocity`) uses trusted
frames only; the monitor (:mod:`sara_app.human.conformance`) checks the trusted motion against
the parameter set and faults the person while it does not hold. A frame with a joint held too
long is refused (the caller counts it; the person ages).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sara_app.human.conformance import Monitor, Violation
from sara_app.human.gate import FLAGS, Gate, GateResult, GateSettings
from sara_app.human.skeleton import FULL_JOINTS
from sara_app.human.velocity import VelocityEstimator


@dataclass(frozen=True)
class IntakeSettings:
    """The gate's settings and the monitor's ``recover_s``."""

    gate: GateSettings = GateSettings()
    recover_s: float = 0.5


class Intake:
    """Gate, estimator and monitor of one person (full-skeleton joint order)."""

    def __init__(
        self,
        delta_y_m: float,
        v_max_mps: np.ndarray,
        a_max_mps2: np.ndarray,
        settings: IntakeSettings = IntakeSettings(),
    ) -> None:
        J = len(v_max_mps)
        self.gate = Gate(np.asarray(v_max_mps, float), settings.gate)
        self.estimator = VelocityEstimator(J, delta_y_m, a_max_mps2)
        self.monitor = Monitor(FULL_JOINTS[:J], v_max_mps, a_max_mps2, settings.recover_s)

    def retune(
        self, delta_y_m: float, v_max_mps: np.ndarray, a_max_mps2: np.ndarray,
        settings: IntakeSettings,
    ) -> None:  # fmt: skip
        """New parameters (a scenario edit): what was learned stays, velocity bounds restart."""
        self.gate.retune(v_max_mps, settings.gate)
        self.estimator.retune(delta_y_m, a_max_mps2)
        self.monitor.retune(v_max_mps, a_max_mps2, settings.recover_s)

    def take(
        self, t_s: float, y: np.ndarray, delta_y_m: float, n_measured: int,
        missing: np.ndarray | None = None,
    ) -> tuple[GateResult, np.ndarray, np.ndarray] | None:  # fmt: skip
        """Gate, estimate and monitor one frame ``y (J, 3)``; returns the gate's result and the
        velocity ``(J, 3)`` with its bound ``(J,)`` (arrays owned by the intake), or None when
        the frame is refused. ``missing (J,)``: joints the tracker did not measure (held by the
        gate). A stamp that does not advance raises InputError (nothing is changed then)."""
        if self.estimator.delta_y_m != delta_y_m:  # its velocity error bound grows with it
            self.estimator.retune(delta_y_m, self.estimator.a_max)
        self.estimator.check_stamp(t_s)
        g = self.gate.check(t_s, y, delta_y_m, n_measured, missing)
        if g.refused:
            return None
        v, dv = self.estimator.update(t_s, g.y, g.trusted)
        self.monitor.observe(t_s, g.y, g.trusted, delta_y_m, g.jump_speed_mps)
        return g, v, dv

    def fault(self, human_id: str) -> str | None:
        return self.monitor.fault(human_id)

    def counts(self) -> dict[str, int]:
        """Flags of the gate and the monitor since the intake was built."""
        return {**self.gate.counts, **self.monitor.counts}


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
) -> Screening:
    """Every frame ``y (T, J, 3)`` through a fresh intake (:meth:`Intake.take`, as a live cell
    takes it: a refused frame feeds neither the estimator nor the monitor)."""
    intake = Intake(delta_y_m, v_max_mps, a_max_mps2, settings or IntakeSettings())
    T, J = y.shape[:2]
    held = np.zeros((T, J), bool)
    flags = np.zeros((T, J, len(FLAGS)), bool)
    refused = np.zeros(T, bool)
    violations: list[Violation] = []
    m = intake.monitor
    for i in range(T):
        t = float(times_s[i])
        intake.take(t, y[i], delta_y_m, J)
        g = intake.gate.out  # this frame's gate result, refused or not
        held[i], flags[i], refused[i] = ~g.trusted, g.flags, g.refused
        if m.last_violation_s == t:  # the monitor found violations in this frame
            violations += m.last
    return Screening(held, flags, refused, violations, intake.counts(), m.peak_speed_mps,
                     m.peak_acc_mps2)  # fmt: skip
