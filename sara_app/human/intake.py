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

from sara_app.human.conformance import Monitor
from sara_app.human.gate import Gate, GateResult, GateSettings
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
        self, t_s: float, y: np.ndarray, delta_y_m: float, n_measured: int
    ) -> tuple[GateResult, np.ndarray, np.ndarray] | None:
        """Gate, estimate and monitor one frame ``y (J, 3)``; returns the gate's result and the
        velocity ``(J, 3)`` with its bound ``(J,)`` (arrays owned by the intake), or None when
        the frame is refused. A stamp that does not advance raises InputError (nothing is
        changed then)."""
        if self.estimator.delta_y_m != delta_y_m:  # its velocity error bound grows with it
            self.estimator.retune(delta_y_m, self.estimator.a_max)
        self.estimator.check_stamp(t_s)
        g = self.gate.check(t_s, y, delta_y_m, n_measured)
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
