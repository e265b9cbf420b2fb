"""Bone lengths a human body can have: a skeleton outside them is no person's measurement.

The tracking gate (:mod:`sara_app.human.gate`) checks each bone against the person's own length,
but it learns that length from the person's first frames: a skeleton whose joints all sit at
one point (a tracker's degenerate output, or a hostile publisher) taught it zero-length bones
and was trusted as a person, while a real person's hands could be 0.7 m from that point and
the robot moved (hostile-tracker probe, 2026-11-30). So every measured bone of every frame must
also lie within :data:`BONE_RANGE_M` (widened by the measurement noise, ``2 delta_y``): a bone
outside it is inconsistent like one off the person's own length, and the gate blames its ends
(a joint that jumped, else both) and holds them. A person never seen whole has no history to
hold: their held joints' sets are unbounded, the robot stays on its failsafe.

The ranges are generous, for adults measured by any supported tracker, whose joint centres
differ (a head joint at the nose, the ear or the skull's centre; a neck at the shoulders'
midpoint or on the spine; a pelvis at the hips' midpoint or the sacrum). Recorded extremes of
the project's recordings (CMU walk, run, boxing and subject 62's construction work, TUM's
table-side collaboration, reconstruction failures included), 2026-11-30: head-neck 0.17-0.27 m,
neck-pelvis 0.24-0.35, neck-shoulder 0.13-0.21, upper arm 0.26-0.35, forearm 0.19-0.29,
pelvis-hip 0.14-0.16, thigh 0.41-0.43, shank 0.41-0.46; Drillis and Contini's segment ratios
give upper arms of 0.26-0.39 m, forearms 0.20-0.31, thighs 0.34-0.51 and shanks 0.34-0.52 for
statures of 1.4-2.1 m. Each range's lower end is at most about half of the smallest of these,
its upper end at least 1.3 times the largest.
"""

from __future__ import annotations

import numpy as np

BONE_RANGE_M: dict[tuple[str, str], tuple[float, float]] = {
    ("head", "neck"): (0.04, 0.50),
    ("neck", "pelvis"): (0.15, 0.90),
    ("neck", "l_shoulder"): (0.05, 0.40),
    ("neck", "r_shoulder"): (0.05, 0.40),
    ("l_shoulder", "l_elbow"): (0.12, 0.55),
    ("r_shoulder", "r_elbow"): (0.12, 0.55),
    ("l_elbow", "l_wrist"): (0.10, 0.50),
    ("r_elbow", "r_wrist"): (0.10, 0.50),
    ("pelvis", "l_hip"): (0.03, 0.35),
    ("pelvis", "r_hip"): (0.03, 0.35),
    ("l_hip", "l_knee"): (0.18, 0.70),
    ("r_hip", "r_knee"): (0.18, 0.70),
    ("l_knee", "l_ankle"): (0.18, 0.70),
    ("r_knee", "r_ankle"): (0.18, 0.70),
}
"""Per bone of :data:`sara_app.human.tracking_settings.BONES`: the shortest and longest length
(m) of a measured adult's bone on any supported tracker (see the module notes)."""


def bone_ranges(bones: np.ndarray, joints: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """``(shortest_m (B,), longest_m (B,))`` for ``bones (B, 2)`` (indices into ``joints``);
    the gate's kernel checks them (:func:`sara_app.human.gate_kernels.gate_frame`)."""
    pairs = [(joints[a], joints[b]) for a, b in bones]
    lo = np.array([BONE_RANGE_M[p][0] for p in pairs], dtype=float)
    hi = np.array([BONE_RANGE_M[p][1] for p in pairs], dtype=float)
    return lo, hi


UNMEASURED_LEG_REACH_M = {"hip": 0.2, "knee": 0.7, "ankle": 1.2}
"""The farthest each leg joint (either side) can be from the pelvis joint (the midpoint of the
hips, or SaRA's torso-base marker), m: the pelvis-to-hip offset (about 0.1-0.15 m) for a hip,
plus a tall adult's thigh (about 0.5 m) for a knee, plus the shank (about 0.5 m) for an ankle;
0.2, 0.7 and 1.2 m are the named conservative round-ups (the CMU subjects of the walk, run,
boxing and bench-work recordings: at most 0.16, 0.58 and 1.02 m). The foot's own size is its
body part's thickness, as for a measured foot. Where an upper-body tracker leaves the legs
unmeasured, each leg is a ball at the pelvis grown by the ankle's reach
(:mod:`sara_app.human.widening`)."""
