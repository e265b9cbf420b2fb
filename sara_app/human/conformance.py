"""Live conformance monitor: does the observed motion keep to the parameter set's bounds?

Every guarantee the shield gives rests on the person moving within the active parameter set
(``v_max``, ``a_max`` per joint) and the tracker keeping within ``delta_y``. The monitor checks,
per person and joint, two necessary conditions on the motion the tracking quality gate trusts
(:mod:`sara_app.human.gate`), over spans of 1 to ``2**(SPANS-1)`` frames back (a short span sees
a jump, a long one a small excess sustained); a violation proves that an assumption does not
hold right now:

- **speed**: ``|y_2 - y_0| <= 2 delta_y + v_max (t_2 - t_0)`` (and the gate's ``jump`` of a joint
  that only jumped, the same test against its last trusted position); value reported:
  ``(|y_2 - y_0| - 2 delta_y) / (t_2 - t_0)``;
- **acceleration**: a point whose acceleration is bounded by ``a_max`` lies within
  ``a_max (t_1 - t_0)(t_2 - t_1) / 2`` of the chord between its positions at ``t_0`` and ``t_2``
  (the linear interpolation error bound), so a measured midpoint lies within that plus
  ``2 delta_y`` of the measured chord; value reported: the least acceleration that explains the
  measured distance, ``2 (d - 2 delta_y) / ((t_1 - t_0)(t_2 - t_1))``;
- **displacement** (where the parameter set bounds it, R_VEL's table
  :class:`~sara_app.human.params.DisplacementBound`): ``|y_2 - y_0| - 2 delta_y <= D(t_2 -
  t_0)`` for every trusted position up to the table's horizon back (the last
  ``DISPLACEMENT_FRAMES`` frames; a tracker faster than that many frames per horizon is checked
  over the part of the horizon they cover); value reported: that distance, in m;
- **rise** (a person whose legs are not measured, where the parameter set bounds those legs
  below the pelvis, :mod:`sara_app.human.legs`): ``z_2 - z_0 <= 2 delta_y + rise_max (t_2 -
  t_0)`` for the joints it bounds (the pelvis); value reported: ``(z_2 - z_0 - 2 delta_y) /
  (t_2 - t_0)``;
- **stated velocity** (a tracker that states velocities, :mod:`sara_app.human.stated_velocity`):
  the stated velocity's ball and the estimate's from the positions do not meet; value reported:
  ``|v_stated - v_estimated|``, bound the sum of their two bounds (m/s).

The fallback is the failsafe: a person with a violation is a fault (the robot stays on its
verified failsafe) until frames stamped ``recover_s`` after their last violation show them
within bounds; messages that stop make them age into the stale-measurement fault instead.
``recover_s`` is longer than the velocity estimator's reach (8 frames), so no estimate made
from a violating frame is used once the fault lifts. A wider parameter set as fallback would
need per-person parameters in the compiled kernels; not done.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sara_app.errors import ParameterError
from sara_app.human.conformance_kernels import observe_displacement, observe_frame

QUANTITIES = ("speed", "acceleration", "rise", "displacement", "stated_velocity")


@dataclass(frozen=True)
class Violation:
    """One joint beyond its bound: ``quantity`` in ``QUANTITIES``, ``value`` and ``bound`` in
    m/s, m/s^2 or (displacement) m, ``t_s`` the frame's stamp."""

    joint: str
    quantity: str
    value: float
    bound: float
    t_s: float


SPANS = 5
"""Spans checked: 1, 2, 4, 8 and 16 frames back."""
DISPLACEMENT_FRAMES = 128
"""Frames kept for the displacement check: a 0.5 s table at up to 256 Hz."""


@dataclass
class Monitor:
    """The monitor of one person; ``joints`` names ``v_max_mps``/``a_max_mps2`` ``(J,)``;
    ``rise_max_mps (J,)``: the upward speed bounds (``inf``: a joint without; empty: none);
    ``disp_m (J, N)``, ``disp_step_s``: the displacement bound (``N = 0``: none)."""

    joints: tuple[str, ...]
    v_max_mps: np.ndarray
    a_max_mps2: np.ndarray
    recover_s: float = 0.5
    rise_max_mps: np.ndarray = field(default_factory=lambda: np.empty(0))
    disp_m: np.ndarray = field(default_factory=lambda: np.empty((0, 0)))
    disp_step_s: float = 1.0
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(QUANTITIES, 0))
    """Frames x joints beyond a bound, per quantity, since the monitor was built."""
    last: list[Violation] = field(default_factory=list)
    """The violations of the newest frame that had any."""
    last_violation_s: float = -np.inf
    newest_s: float = -np.inf

    def __post_init__(self) -> None:
        if not self.recover_s > 0:
            raise ParameterError(f"monitor recover_s = {self.recover_s}; expected > 0")
        self.v_max_mps = np.asarray(self.v_max_mps, dtype=float)
        self.a_max_mps2 = np.asarray(self.a_max_mps2, dtype=float)
        J, N = len(self.joints), 2 ** (SPANS - 1) + 1
        self.rise_max_mps = _rise_bounds(self.rise_max_mps, J)
        self.disp_m = _disp_table(self.disp_m, J)
        self._t = np.full(N, -np.inf)  # newest first
        self._y = np.zeros((N, J, 3))
        self._ok = np.zeros((N, J), bool)
        self._speed = np.zeros(J)  # the newest frame's, per joint (owned, reused)
        self._acc = np.zeros(J)
        self._rise = np.zeros(J)
        self._d_t = np.full(DISPLACEMENT_FRAMES, -np.inf)  # circular, next slot self._d_slot
        self._d_y = np.zeros((DISPLACEMENT_FRAMES, J, 3))
        self._d_ok = np.zeros((DISPLACEMENT_FRAMES, J), bool)
        self._d_slot = 0
        self._d_value = np.zeros(J)
        self._d_bound = np.full(J, np.inf)
        self.peak_speed_mps = np.zeros(J)
        """The largest speed and acceleration any frame needed, per joint (whatever the
        bounds: what a parameter set must allow for this motion to conform)."""
        self.peak_acc_mps2 = np.zeros(J)

    def retune(
        self, v_max_mps: np.ndarray, a_max_mps2: np.ndarray, recover_s: float,
        rise_max_mps: np.ndarray | None = None, disp_m: np.ndarray | None = None,
        disp_step_s: float = 1.0,
    ) -> None:  # fmt: skip
        self.v_max_mps = np.asarray(v_max_mps, dtype=float)
        self.a_max_mps2 = np.asarray(a_max_mps2, dtype=float)
        self.recover_s = recover_s
        self.rise_max_mps = _rise_bounds(rise_max_mps, len(self.joints))
        self.disp_m = _disp_table(disp_m, len(self.joints))
        self.disp_step_s = disp_step_s

    def observe(
        self,
        t_s: float,
        y: np.ndarray,
        trusted: np.ndarray,
        delta_y_m: float,
        jump_speed_mps: np.ndarray,
        rise: bool = False,
    ) -> list[Violation]:
        """One gated frame ``y (J, 3)`` with the gate's ``trusted (J,)`` and, for joints that
        only jumped (held by the gate, bones consistent), the speed they needed
        ``jump_speed_mps (J,)`` (0 elsewhere); ``rise``: check the upward speed bounds too (a
        person whose legs are not measured)."""
        speed, acc = self._speed, self._acc
        observe_frame(self._t, self._y, self._ok, float(t_s), np.asarray(y, float),
                      np.asarray(trusted, bool), float(delta_y_m),
                      np.asarray(jump_speed_mps, float), speed, acc, self._rise)  # fmt: skip
        np.maximum(self.peak_speed_mps, speed, out=self.peak_speed_mps)
        np.maximum(self.peak_acc_mps2, acc, out=self.peak_acc_mps2)
        found = [Violation(self.joints[j], "speed", float(speed[j]), float(self.v_max_mps[j]), t_s)
                 for j in np.flatnonzero(speed > self.v_max_mps)]  # fmt: skip
        found += [Violation(self.joints[j], "acceleration", float(acc[j]),
                            float(self.a_max_mps2[j]), t_s)
                  for j in np.flatnonzero(acc > self.a_max_mps2)]  # fmt: skip
        if rise:
            bound = self.rise_max_mps
            found += [Violation(self.joints[j], "rise", float(self._rise[j]), float(bound[j]), t_s)
                      for j in np.flatnonzero(self._rise > bound)]  # fmt: skip
        if self.disp_m.shape[1]:
            value, bound = self._d_value, self._d_bound
            observe_displacement(self._d_t, self._d_y, self._d_ok, self._d_slot, float(t_s),
                                 np.asarray(y, float), np.asarray(trusted, bool),
                                 float(delta_y_m), self.disp_m, float(self.disp_step_s),
                                 self.v_max_mps, value, bound)  # fmt: skip
            self._d_slot = (self._d_slot + 1) % DISPLACEMENT_FRAMES
            found += [Violation(self.joints[j], "displacement", float(value[j]), float(bound[j]),
                                t_s) for j in np.flatnonzero(value > bound)]  # fmt: skip
        self.newest_s = max(self.newest_s, t_s)
        self._record(t_s, found)
        return found

    def contradicted(
        self, t_s: float, joints: np.ndarray, gap_mps: np.ndarray, bound_mps: np.ndarray
    ) -> list[Violation]:
        """Stated velocities the positions contradict in the frame ``t_s`` (observed first):
        ``joints (J,)`` which, ``gap_mps``, ``bound_mps (J,)`` by how much and against what."""
        found = [Violation(self.joints[j], "stated_velocity", float(gap_mps[j]),
                           float(bound_mps[j]), t_s) for j in np.flatnonzero(joints)]  # fmt: skip
        self._record(t_s, found)
        return found

    def _record(self, t_s: float, found: list[Violation]) -> None:
        """A frame's violations (more of the same frame's join those found before)."""
        if not found:
            return
        self.last = self.last + found if self.last_violation_s == t_s else found
        self.last_violation_s = t_s
        for f in found:
            self.counts[f.quantity] += 1

    @property
    def violating(self) -> bool:
        """Within ``recover_s`` of the last violation (by the frames' own stamps)."""
        return self.newest_s - self.last_violation_s < self.recover_s

    def fault(self, human_id: str) -> str | None:
        """The person's fault string while violating, else None."""
        if not self.violating or not self.last:
            return None
        v = self.last[0]
        more = f" (+{len(self.last) - 1} more)" if len(self.last) > 1 else ""
        return (
            f"human {human_id!r}: {v.joint} {v.quantity} {v.value:.2f} > bound {v.bound:.2f}"
            f"{more}; failsafe until {self.recover_s} s within bounds"
        )


def _disp_table(disp_m: np.ndarray | None, n_joints: int) -> np.ndarray:
    """``(J, N)`` displacement table (None or empty: ``(J, 0)``, none); raises on another shape
    or a value that is not finite and >= 0."""
    if disp_m is None or np.size(disp_m) == 0:
        return np.zeros((n_joints, 0))
    table = np.ascontiguousarray(disp_m, dtype=float)
    good = table.ndim == 2 and table.shape[0] == n_joints
    if not (good and (np.isfinite(table) & (table >= 0)).all()):
        raise ParameterError(
            f"monitor displacement table of shape {np.shape(disp_m)}; expected ({n_joints}, N) "
            "finite distances >= 0"
        )
    return table


def _rise_bounds(rise_max_mps: np.ndarray | None, n_joints: int) -> np.ndarray:
    """``(J,)`` upward speed bounds (``inf``: none; None or empty: none for any joint); raises
    on another shape or a bound <= 0."""
    if rise_max_mps is None or np.size(rise_max_mps) == 0:
        return np.full(n_joints, np.inf)
    bound = np.asarray(rise_max_mps, dtype=float)
    if bound.shape != (n_joints,) or not (bound > 0).all():
        raise ParameterError(
            f"monitor rise_max_mps {rise_max_mps!r}; expected {n_joints} bounds > 0 (inf: none)"
        )
    return bound
