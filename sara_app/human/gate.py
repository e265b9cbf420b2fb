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
  joints all passed the jump test. An
  inconsistent bone is blamed on its end joints that jumped or are held; on both when neither
  (conservative: holding a good joint only widens its set). ``bone_tol_m`` covers how much
  trackers' joint centres drift along a bone (soft tissue, joint-centre estimation); a named,
  measured tolerance, not a physical bound.
- **Frozen**: a joint whose coordinates repeat exactly while another measured joint of the same
  skeleton changes. A real tracker's noise never repeats a value; a frozen marker does. The
  joint is distrusted from the first repeated frame on (its true position at that frame is the
  repeated value).

A joint that only jumped stays trusted and flagged: a glitch along its bones cannot be told
from a person faster than the set allows, and the monitor puts that person on the failsafe.
A joint blamed for a bone or frozen is distrusted ("held"): it is replaced by its last trusted
position ``y_T`` and its position uncertainty grows soundly by ``v_max (t - t_T)`` (the
returned ``extra_m``, applied by :mod:`sara_app.human.widening`; its velocity is unknown: the
estimator excludes such frames).
It is trusted again as soon as a frame passes all three checks against the held state. A joint
held for longer than ``max_hold_s`` makes the whole frame refused (counted; the person ages and
the shield's stale-measurement rule brakes the robot).

Only the first ``n_measured`` joints are checked (an upper-body source places the legs at the
pelvis; they are covered by :mod:`sara_app.human.widening`, not measured).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sara_app.errors import ParameterError
from sara_app.human.skeleton import FULL_JOINTS

BONES: tuple[tuple[str, str], ...] = (
    ("head", "neck"),
    ("neck", "pelvis"),
    ("neck", "l_shoulder"),
    ("neck", "r_shoulder"),
    ("l_shoulder", "l_elbow"),
    ("r_shoulder", "r_elbow"),
    ("l_elbow", "l_wrist"),
    ("r_elbow", "r_wrist"),
    ("pelvis", "l_hip"),
    ("pelvis", "r_hip"),
    ("l_hip", "l_knee"),
    ("r_hip", "r_knee"),
    ("l_knee", "l_ankle"),
    ("r_knee", "r_ankle"),
)
"""Joint pairs at a (nearly) constant distance on every supported source (the neck and pelvis
are the midpoints of the shoulders and hips, or markers on the spine)."""

FROZEN_EPS_M = 1e-9
"""A coordinate change below this is a repeat (a frozen output, not motion or noise)."""

FLAGS = ("jump", "bone", "frozen", "missing")
"""The gate's per-joint flags, in the order of :attr:`GateResult.flags`' columns (``missing``:
the tracker said it has no measurement of the joint, :mod:`sara_app.human.trackers`)."""


@dataclass(frozen=True)
class GateSettings:
    """``bone_tol_m``: allowed drift of a bone length beyond ``2 delta_y``; ``learn_frames``:
    frames whose median gives the person's bone lengths; ``max_hold_s``: a joint held longer
    refuses the frame."""

    bone_tol_m: float = 0.05
    learn_frames: int = 15
    max_hold_s: float = 0.5
    known_bones_m: tuple[tuple[str, str, float], ...] = ()
    """Bone lengths given by the scenario ``(joint, joint, m)``: checked from the first frame;
    the other bones are learned."""

    def __post_init__(self) -> None:
        if not (self.bone_tol_m >= 0 and self.learn_frames >= 1 and self.max_hold_s > 0):
            raise ParameterError(
                f"gate bone_tol_m = {self.bone_tol_m}, learn_frames = {self.learn_frames}, "
                f"max_hold_s = {self.max_hold_s}; expected >= 0, >= 1, > 0"
            )
        for a, b, length in self.known_bones_m:
            if (a, b) not in BONES or not (0 < length < 2):
                raise ParameterError(
                    f"known bone {a}-{b} of {length} m; expected one of "
                    f"{', '.join(f'{x}-{y}' for x, y in BONES)} with 0 < length < 2 m"
                )


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
        self.length_m = self._known(self.settings)
        """``(B,)`` the bone lengths checked (nan: not known yet, being learned)."""
        self.y_trusted = np.zeros((J, 3))
        self.t_trusted = np.full(J, -np.inf)
        self.y_prev = np.full((J, 3), np.nan)
        self.first_seen_s = np.full(J, -np.inf)  # when each joint's current value first came
        self.since_s = np.full(J, np.nan)  # when the current hold began (nan: not held)
        self._learn: list[np.ndarray] = []
        self._none = np.zeros(J, bool)  # no joint missing (a frame without confidences)
        self.out = GateResult(np.zeros((J, 3)), np.zeros(J), np.ones(J, bool),
                              np.zeros((J, len(FLAGS)), bool), np.zeros(J))  # fmt: skip

    def retune(self, v_max_mps: np.ndarray, settings: GateSettings) -> None:
        """New bounds (a scenario edit); what was learned and held stays, bone lengths the
        scenario now gives replace it."""
        self.v_max_mps = np.asarray(v_max_mps, dtype=float)
        self.settings = settings
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
            y = np.where(lost[:, None], self.y_trusted, y)  # a held joint's value, never NaN
        m = (np.arange(y.shape[0]) < n_measured) & ~lost
        held = np.isfinite(self.since_s)
        dist = np.linalg.norm(y - self.y_trusted, axis=1)
        reach = 2.0 * delta_y_m + self.v_max_mps * (t_s - self.t_trusted)
        jump = m & np.isfinite(self.t_trusted) & (dist > reach)
        with np.errstate(divide="ignore", invalid="ignore"):
            out.jump_speed_mps[:] = np.where(
                jump, (dist - 2.0 * delta_y_m) / (t_s - self.t_trusted), 0.0
            )
        same = m & np.all(np.abs(y - self.y_prev) <= FROZEN_EPS_M, axis=1)
        moved = m & ~same & np.isfinite(self.y_prev[:, 0])
        frozen = same & (moved.any() | held)
        bone = m & self._bone_blame(y, delta_y_m, jump | frozen | held, m)
        out.flags[:, 0], out.flags[:, 1], out.flags[:, 2], out.flags[:, 3] = (
            jump,
            bone,
            frozen,
            lost,
        )
        bad = bone | frozen | lost
        # A frozen joint's repeated value was a measurement when it first came: held from then.
        restart = frozen & (self.t_trusted > self.first_seen_s)
        self.t_trusted[restart] = self.first_seen_s[restart]
        self.y_trusted[restart] = y[restart]
        start = np.where(frozen, np.minimum(self.first_seen_s, t_s), t_s)
        self.since_s = np.where(bad, np.where(held, self.since_s, start), np.nan)
        good = ~bad
        self.y_trusted[good] = y[good]
        self.t_trusted[good] = t_s
        out.trusted[:] = good
        out.y[:] = np.where(good[:, None], y, self.y_trusted)
        out.extra_m[:] = np.where(good, 0.0, self.v_max_mps * (t_s - self.t_trusted))
        held_s = np.where(bad, t_s - self.since_s, 0.0)
        out.refused = bool((held_s > self.settings.max_hold_s).any()) or bool(
            (lost & ~np.isfinite(self.t_trusted)).any()
        )
        self.first_seen_s = np.where(same, self.first_seen_s, t_s)
        self.y_prev[:] = y
        if np.isnan(self.length_m).any() and not (bad | jump)[m].any():
            self._learn_bones(y)
        for k, name in enumerate(FLAGS):
            self.counts[name] += int(out.flags[:, k].sum())
        self.counts["refused"] += int(out.refused)
        return out

    def _bone_blame(
        self, y: np.ndarray, delta_y_m: float, suspect: np.ndarray, measured: np.ndarray
    ) -> np.ndarray:
        """``(J,)`` joints blamed for an inconsistent bone of two measured joints: its suspect
        ends, else both."""
        blame = np.zeros(y.shape[0], dtype=bool)
        if not len(self.bones):
            return blame
        a, b = self.bones[:, 0], self.bones[:, 1]
        length = np.linalg.norm(y[a] - y[b], axis=1)
        with np.errstate(invalid="ignore"):  # nan: a bone not known yet is not checked
            off = np.abs(length - self.length_m) > 2.0 * delta_y_m + self.settings.bone_tol_m
        off &= measured[a] & measured[b]
        sa, sb = suspect[a], suspect[b]
        either = sa | sb
        blame[a[off & (sa | ~either)]] = True
        blame[b[off & (sb | ~either)]] = True
        return blame

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
