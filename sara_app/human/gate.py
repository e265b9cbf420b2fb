"""Tracking quality gate: which joints of a skeleton are trusted as measurements.

Real trackers swap markers (a wrist jumps to the head), freeze them (a wrist held still while
the arm moves) and emit one-frame spikes. The models assume every measured joint lies within
``delta_y`` of the true joint; a glitch breaks that silently and, through the velocity
estimate, becomes a huge "acceleration". The gate checks every measured joint of every frame
against three necessary conditions and never trusts a joint that fails one:

- **Jump** (what the parameter set allows between two frames): a joint last trusted at
  ``y_T`` at time ``t_T`` and moving at most ``v_max`` lies within ``2 delta_y + v_max (t - t_T)``
  of its new measurement (both measurements within ``delta_y``). Failing this, the frame is a
  glitch or the person is faster than the set allows (the conformance monitor,
  :mod:`sara_app.human.conformance`, answers for it).
- **Bone**: the distance between two joints joined by a bone stays within
  ``2 delta_y + bone_tol_m`` of the person's own bone length: given by the scenario
  (``known_bones_m``) or learned online as the median of the first ``learn_frames`` frames whose
  joints all passed the jump test; and from the first frame on within ``2 delta_y`` of a
  person's range (:mod:`sara_app.human.anatomy`: a skeleton collapsed to a point taught the
  gate zero-length bones and was trusted). An
  inconsistent bone is blamed on its end joints that jumped or are held; on both when neither
  (conservative: holding a good joint only widens its set). ``bone_tol_m`` covers how much
  trackers' joint centres drift along a bone (soft tissue, joint-centre estimation); a named,
  measured tolerance, not a physical bound.
- **Frozen**: a joint whose coordinates repeat exactly while another measured joint of the same
  skeleton changes. A real tracker's noise never repeats a value; a frozen marker does. The
  joint is distrusted from the first repeated frame on (its true position at that frame is the
  repeated value).

A joint that fails a check is distrusted ("held") until a frame passes all three against its
last trusted position ``y_T`` (stamped ``t_T``): then the history and the newest measurement
agree again. Meanwhile neither is discarded (DESIGN 10, "a measurement is never discarded for
history"): a jump is ambiguous (the old position may be the glitch and the new one the truth: a
tracker that recovers from a wrong association, a person found again after an occlusion), so
the joint's set must hold both the history, ``B(y_T, delta_T + v_max (t - t_T))``, and the
measurement, ``B(y, delta_y)`` (a frozen value ages from when it first came; a missing joint
has no measurement). The gate returns the smallest ball enclosing the two (:func:`enclose`): its
centre as the joint's position and its radius beyond ``delta_y`` as ``extra_m``, which
:mod:`sara_app.human.widening` adds to every model's capsules containing the joint (each model
is a union of balls around the measured joints grown by ``delta_y``, so it stays sound for a
joint known to within ``delta_y + extra``). A held joint's velocity is unknown: the estimator
excludes such frames, so no model's set is centred on a velocity measured across a jump.

A joint that only jumped (its bones are consistent: the whole skeleton moved, or a joint moved
faster than the set allows) also reports the speed it needed (``jump_speed_mps``): the
conformance monitor puts that person on the failsafe. A joint blamed for a bone (a swapped or
spiking marker) does not: its widened set covers it. A joint held for longer than
``max_hold_s`` makes the whole frame refused (counted; the person ages and the shield's
stale-measurement rule brakes the robot).

Only the first ``n_measured`` joints are checked (an upper-body source places the legs at the
pelvis; they are covered by :mod:`sara_app.human.widening`, not measured).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sara_app.errors import InputError
from sara_app.human.anatomy import bone_ranges
from sara_app.human.gate_kernels import (
    ALL_GOOD,
    CLEAN,
    FLAGGED,
    REFUSED,
    gate_advance,
    gate_frame,
)
from sara_app.human.skeleton import FULL_JOINTS
from sara_app.human.tracking_settings import BONES, GateSettings
from sara_app.kernel_types import as_f8

FLAGS = ("jump", "bone", "frozen", "missing")
"""The gate's per-joint flags, in the order of :attr:`GateResult.flags`' columns (``missing``:
the tracker said it has no measurement of the joint, :mod:`sara_app.human.trackers`)."""


@dataclass
class GateResult:
    """One frame through the gate (arrays owned by the gate, valid until its next call).

    ``y`` ``(J, 3)``: measured joints where trusted, the last trusted position where held;
    ``extra_m`` ``(J,)``: position uncertainty beyond ``delta_y``; ``trusted`` ``(J,)``;
    ``flags`` ``(J, len(FLAGS))`` what this frame's checks found; ``refused``: a joint was
    held longer than ``max_hold_s`` (the caller refuses the frame)."""

    y: np.ndarray
    extra_m: np.ndarray
    trusted: np.ndarray
    flags: np.ndarray
    jump_speed_mps: np.ndarray
    """``(J,)`` the speed a jumping joint needed beyond the noise, ``(|dy| - 2 delta_y) / dt``."""
    refused: bool = False

    @property
    def held(self) -> bool:
        return not bool(self.trusted.all())


def why(flags: np.ndarray) -> int:
    """The index in ``FLAGS`` that says why a joint with ``flags (len(FLAGS),)`` is held: the
    glitch (missing, frozen, bone) before a jump (a glitch usually jumps too)."""
    return len(FLAGS) - 1 - int(np.argmax(flags[::-1]))


def enclose(
    c1: np.ndarray, r1: np.ndarray, c2: np.ndarray, r2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The smallest ball enclosing the balls ``B(c1, r1)`` and ``B(c2, r2)``, per row: centres
    ``(N, 3)``, radii ``(N,)``; returns the centres ``(N, 3)`` and radii ``(N,)``. A radius of
    ``-inf`` is no ball (the other is returned). For distance ``d`` between the centres the
    radius is ``max(r1, r2, (d + r1 + r2) / 2)`` and the centre lies on the segment from
    ``c1`` to ``c2``, ``(R - r1) / d`` of the way."""
    d = np.linalg.norm(c2 - c1, axis=1)
    with np.errstate(invalid="ignore"):  # -inf + inf: one ball missing
        R = np.maximum(np.maximum(r1, r2), np.nan_to_num((d + r1 + r2) / 2.0, nan=-np.inf))
    with np.errstate(divide="ignore", invalid="ignore"):
        w = np.where(d > 0.0, (R - r1) / d, np.where(r2 > r1, 1.0, 0.0))
    w = np.clip(np.nan_to_num(w, nan=0.0, posinf=1.0, neginf=0.0), 0.0, 1.0)
    return c1 + w[:, None] * (c2 - c1), R


def bone_indices(joints: tuple[str, ...] = FULL_JOINTS) -> np.ndarray:
    """``(B, 2)`` joint indices of the bones whose joints are all in ``joints``."""
    return np.array([[joints.index(a), joints.index(b)] for a, b in BONES
                     if a in joints and b in joints], dtype=np.int64).reshape(-1, 2)  # fmt: skip


@dataclass
class Gate:
    """The gate of one person. ``v_max_mps`` ``(J,)``; the bone lengths are the settings'
    known ones, the rest learned online."""

    v_max_mps: np.ndarray
    settings: GateSettings = GateSettings()
    bones: np.ndarray = field(default_factory=bone_indices)
    counts: dict[str, int] = field(default_factory=lambda: dict.fromkeys(FLAGS + ("refused",), 0))
    """Joint-frames flagged per check, and frames refused, since the gate was built."""

    def __post_init__(self) -> None:
        self.v_max_mps = np.asarray(self.v_max_mps, dtype=float)
        J = len(self.v_max_mps)
        # an upper-body person (J = 9, the full skeleton's first joints) has no leg bones
        self.bones = self.bones[(self.bones < J).all(axis=1)]
        self.length_m = self._known(self.settings)
        """``(B,)`` the bone lengths checked (nan: not known yet, being learned)."""
        self._ranges()
        self.y_trusted = np.zeros((J, 3))
        self.t_trusted = np.full(J, -np.inf)
        self.dy_trusted = np.zeros(J)  # delta_y of each joint's last trusted measurement
        self.y_prev = np.full((J, 3), np.nan)
        self.first_seen_s = np.full(J, -np.inf)  # when each joint's current value first came
        self.since_s = np.full(J, np.nan)  # when the current hold began (nan: not held)
        self.last_flag: tuple[int, int, float] | None = None
        """``(joint, index in FLAGS, stamp)`` of the newest flagged joint (None: none yet)."""
        self._learn: list[np.ndarray] = []
        self._none = np.zeros(J, bool)  # no joint missing (a frame without confidences)
        self._same = np.zeros(J, bool)  # the kernel's: joints repeated exactly this frame
        self.out = GateResult(np.zeros((J, 3)), np.zeros(J), np.ones(J, bool),
                              np.zeros((J, len(FLAGS)), bool), np.zeros(J))  # fmt: skip

    def retune(self, v_max_mps: np.ndarray, settings: GateSettings) -> None:
        """New bounds (a scenario edit); what was learned and held stays, bone lengths the
        scenario now gives replace it."""
        self.v_max_mps = np.asarray(v_max_mps, dtype=float)
        self.settings = settings
        self._ranges()
        known = self._known(settings)
        self.length_m = np.where(np.isnan(known), self.length_m, known)

    def check(
        self, t_s: float, y: np.ndarray, delta_y_m: float, n_measured: int,
        missing: np.ndarray | None = None,
    ) -> GateResult:  # fmt: skip
        """Gate one frame ``y (J, 3)`` stamped ``t_s`` (see the module notes). A joint that only
        jumped is trusted (flagged: the conformance monitor answers for it); a joint blamed
        for a bone, frozen, or ``missing`` ``(J,)`` (the tracker has no measurement of it; its
        ``y`` row may be NaN) is held. A missing joint never trusted before refuses the
        frame: there is no position to hold."""
        out = self.out
        lost = self._none if missing is None else np.asarray(missing, bool)
        if lost.any():
            y = np.where(lost[:, None], self.y_trusted, y)
        y = as_f8(y)
        if y.shape != self.y_trusted.shape or lost.shape != self.t_trusted.shape:
            raise InputError(
                f"gate: frame of shape {y.shape}, missing flags {lost.shape}; expected "
                f"{self.y_trusted.shape} and {self.t_trusted.shape}"
            )
        s = self.settings
        bits = gate_frame(
            float(t_s), y, float(delta_y_m), int(n_measured), lost, self.v_max_mps, self.bones,
            self.length_m, self.shortest_m, self.longest_m, s.bone_tol_m, s.max_hold_s,
            self.y_trusted, self.t_trusted, self.dy_trusted, self.y_prev, self.first_seen_s,
            self.since_s, out.flags, out.jump_speed_mps, out.trusted, self._same,
        )  # fmt: skip
        self._enclose_held(t_s, y, delta_y_m, out.trusted, out.flags[:, 2], lost,
                           all_good=bool(bits & ALL_GOOD))  # fmt: skip
        out.refused = bool(bits & REFUSED)
        gate_advance(float(t_s), y, self._same, self.first_seen_s, self.y_prev)
        if bits & CLEAN and np.isnan(self.length_m).any():
            self._learn_bones(y)
        self._tally(t_s, flagged=bool(bits & FLAGGED))
        return out

    def _tally(self, t_s: float, flagged: bool) -> None:
        """The frame's flags into :attr:`last_flag` and :attr:`counts` (``flagged``: some joint
        is; without, only a refusal can count)."""
        out = self.out
        if flagged:
            j = int(np.flatnonzero(out.flags.any(axis=1))[0])
            self.last_flag = (j, why(out.flags[j]), t_s)
            for k, name in enumerate(FLAGS):
                self.counts[name] += int(out.flags[:, k].sum())
        self.counts["refused"] += int(out.refused)

    def _enclose_held(
        self, t_s: float, y: np.ndarray, delta_y_m: float, good: np.ndarray,
        frozen: np.ndarray, lost: np.ndarray, all_good: bool,
    ) -> None:  # fmt: skip
        """``out.y`` and ``out.extra_m``: a trusted joint as measured; a held one as the ball
        enclosing its history and its measurement (see the module notes). ``all_good``:
        ``good`` is all true."""
        out = self.out
        if all_good:  # the common frame: nothing held, nothing to enclose
            out.y[:] = y
            out.extra_m[:] = 0.0
            return
        age = np.maximum(t_s - self.t_trusted, 0.0)
        r_hist = self.dy_trusted + self.v_max_mps * age
        # A frozen value is a measurement from when it first came; a missing joint has none.
        since = np.where(frozen, np.minimum(self.first_seen_s, t_s), t_s)
        r_meas = np.where(lost, -np.inf, delta_y_m + self.v_max_mps * (t_s - since))
        centre, radius = enclose(self.y_trusted, r_hist, y, r_meas)
        out.y[:] = np.where(good[:, None], y, centre)
        out.extra_m[:] = np.where(good, 0.0, np.maximum(radius - delta_y_m, 0.0))

    def _ranges(self) -> None:
        """``shortest_m``, ``longest_m`` ``(B,)``: a person's bone lengths (no bounds with the
        anatomy check off)."""
        if self.settings.anatomy:
            self.shortest_m, self.longest_m = bone_ranges(self.bones, FULL_JOINTS)
        else:
            self.shortest_m = np.full(len(self.bones), -np.inf)
            self.longest_m = np.full(len(self.bones), np.inf)

    def _learn_bones(self, y: np.ndarray) -> None:
        a, b = self.bones[:, 0], self.bones[:, 1]
        self._learn.append(np.linalg.norm(y[a] - y[b], axis=1))
        if len(self._learn) >= self.settings.learn_frames:
            learned = np.median(np.array(self._learn), axis=0)
            self.length_m = np.where(np.isnan(self.length_m), learned, self.length_m)
            self._learn.clear()

    def _known(self, settings: GateSettings) -> np.ndarray:
        """``(B,)`` the scenario's bone lengths, nan where not given."""
        out = np.full(len(self.bones), np.nan)
        given = {(a, b): v for a, b, v in settings.known_bones_m}
        for k, (a, b) in enumerate(self.bones):
            out[k] = given.get((FULL_JOINTS[a], FULL_JOINTS[b]), np.nan)
        return out
