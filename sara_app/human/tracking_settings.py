"""What a scenario says about tracking, apart from the code that tracks: the tracking gate's
settings (:class:`GateSettings`, the bones it checks) and the intake's
(:class:`IntakeSettings`, the stale-tracker rule).

Kept free of compiled kernels: a scenario is read by processes that never track a person (the
reference controller, the replayer, the API and the dashboard), and the gate's module loads
its kernels when imported (:mod:`sara_app.human.gate`, :mod:`sara_app.human.intake`).
"""

from __future__ import annotations

from dataclasses import dataclass

from sara_app.errors import ParameterError

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
    anatomy: bool = True
    """Every bone is also checked against a person's range (:mod:`sara_app.human.anatomy`).
    Off only for synthetic point sets that are no bodies (tests of the monitor)."""

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


STALE_AFTER_S = 0.1
"""A whole skeleton repeated bit-exactly for longer than this, its stamps advancing, is a stale
tracker (a pipeline that stalled and republishes its last pose): a fault until it changes. A
real tracker's noise never repeats every coordinate of a skeleton; a tracker that republishes
each pose once at twice its rate (a 30 Hz camera behind a 60 Hz stream) repeats for one
period, well below this."""


@dataclass(frozen=True)
class IntakeSettings:
    """The gate's settings, the monitor's ``recover_s`` and the stale-tracker rule:
    ``stale_after_s`` (None: off, for noiseless synthetic sources, whose people at rest repeat
    their skeleton exactly)."""

    gate: GateSettings = GateSettings()
    recover_s: float = 0.5
    stale_after_s: float | None = STALE_AFTER_S


DEFAULT_INTAKE = IntakeSettings()
"""The settings of a scenario that says nothing about tracking (frozen: one shared instance)."""
