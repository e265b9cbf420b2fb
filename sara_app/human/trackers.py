"""Body trackers' joint layouts: how their points map to the project's 15-joint skeleton, their
units and what their per-point confidence means.

Three layouts besides COCO-17 and SaRA's markers (:data:`sara_app.human.skeleton.SOURCES`):

- ``azure_kinect``: Azure Kinect body tracking (K4ABT), 32 joints in **millimetres**; confidence
  levels 0 NONE (out of range), 1 LOW (not observed, predicted), 2 MEDIUM, 3 HIGH. The
  project's head, neck and pelvis are K4ABT's ``head``, ``neck`` and ``pelvis`` joints.
- ``blazepose``: MediaPipe BlazePose, 33 world landmarks in metres; confidence is the landmark's
  ``visibility`` in [0, 1]. Head, neck and pelvis are the midpoints of the ears, shoulders and
  hips (BlazePose has no such landmark).
- ``zed_body34`` / ``zed_body38``: Stereolabs ZED, BODY_34 (34 keypoints) or BODY_38 (38; the
  head is the ears' midpoint), in metres (set the SDK's ``coordinate_units`` to METER);
  confidence is the keypoint's ``keypoint_confidence`` in [0, 100] (NaN keypoints: leave the
  point out).

Point names are the SDKs' enum names in lower case. Positions must be in the cell's world
frame (the tracker's extrinsic calibration is applied by the client that publishes them).

Confidence (:func:`joint_confidence`): a point below ``missing_below`` (or left out of a
message that carries confidences) counts as **missing**: its joint is held at its last trusted
position and its sets grow with time, as the tracking gate does for a distrusted joint (a joint
never seen yet refuses the frame). A point below ``low_below`` is **low**: its joint's sets grow
by the scenario's ``inputs.low_confidence_extra_m``. A virtual joint takes the worst of its
points. The thresholds are the SDKs' own level boundaries (Azure, ZED's documented 0-100 scale
at 10 and 50, BlazePose's usual 0.5 visibility cut); how far a low-confidence point may really
be off is not measured here: ``low_confidence_extra_m`` (default 0.10 m) is a named
conservative choice for the safety engineer to confirm with the tracker at hand.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

AZURE_KINECT_JOINTS: tuple[str, ...] = (
    "pelvis", "spine_navel", "spine_chest", "neck", "clavicle_left", "shoulder_left",
    "elbow_left", "wrist_left", "hand_left", "handtip_left", "thumb_left", "clavicle_right",
    "shoulder_right", "elbow_right", "wrist_right", "hand_right", "handtip_right", "thumb_right",
    "hip_left", "knee_left", "ankle_left", "foot_left", "hip_right", "knee_right", "ankle_right",
    "foot_right", "head", "nose", "eye_left", "ear_left", "eye_right", "ear_right",
)  # fmt: skip
"""K4ABT_JOINT_* in enum order (Azure Kinect Body Tracking SDK, ``k4abttypes.h``)."""

BLAZEPOSE_LANDMARKS: tuple[str, ...] = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
    "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_pinky",
    "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel",
    "right_heel", "left_foot_index", "right_foot_index",
)  # fmt: skip
"""MediaPipe PoseLandmark in index order."""

ZED_BODY34_KEYPOINTS: tuple[str, ...] = (
    "pelvis", "naval_spine", "chest_spine", "neck", "left_clavicle", "left_shoulder",
    "left_elbow", "left_wrist", "left_hand", "left_handtip", "left_thumb", "right_clavicle",
    "right_shoulder", "right_elbow", "right_wrist", "right_hand", "right_handtip", "right_thumb",
    "left_hip", "left_knee", "left_ankle", "left_foot", "right_hip", "right_knee", "right_ankle",
    "right_foot", "head", "nose", "left_eye", "left_ear", "right_eye", "right_ear", "left_heel",
    "right_heel",
)  # fmt: skip
"""ZED SDK BODY_34_PARTS in index order."""

ZED_BODY38_KEYPOINTS: tuple[str, ...] = (
    "pelvis", "spine_1", "spine_2", "spine_3", "neck", "nose", "left_eye", "right_eye",
    "left_ear", "right_ear", "left_clavicle", "right_clavicle", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_big_toe",
    "right_big_toe", "left_small_toe", "right_small_toe", "left_heel", "right_heel",
    "left_hand_thumb_4", "right_hand_thumb_4", "left_hand_index_1", "right_hand_index_1",
    "left_hand_middle_4", "right_hand_middle_4", "left_hand_pinky_1", "right_hand_pinky_1",
)  # fmt: skip
"""ZED SDK BODY_38_PARTS in index order (no head keypoint: the head is the ears' midpoint)."""

_LIMB_JOINTS = ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")


def _limbs(name: str) -> dict[str, tuple[str, ...]]:
    """``l_shoulder`` ... ``r_ankle`` from a tracker's ``name.format(side=..., joint=...)``."""
    return {f"{s[0]}_{j}": (name.format(side=s, joint=j),) for s in ("left", "right")
            for j in _LIMB_JOINTS}  # fmt: skip


TRACKER_SOURCES: dict[str, tuple[str, dict[str, tuple[str, ...]]]] = {
    "azure_kinect": ("full", {"head": ("head",), "neck": ("neck",), "pelvis": ("pelvis",),
                              **_limbs("{joint}_{side}")}),
    "blazepose": ("full", {"head": ("left_ear", "right_ear"),
                           "neck": ("left_shoulder", "right_shoulder"),
                           "pelvis": ("left_hip", "right_hip"), **_limbs("{side}_{joint}")}),
    "zed_body34": ("full", {"head": ("head",), "neck": ("neck",), "pelvis": ("pelvis",),
                            **_limbs("{side}_{joint}")}),
    "zed_body38": ("full", {"head": ("left_ear", "right_ear"), "neck": ("neck",),
                            "pelvis": ("pelvis",), **_limbs("{side}_{joint}")}),
}  # fmt: skip
"""Source name -> (skeleton kind, project joint -> tracker points averaged)."""

TRACKER_POINTS: dict[str, tuple[str, ...]] = {
    "azure_kinect": AZURE_KINECT_JOINTS,
    "blazepose": BLAZEPOSE_LANDMARKS,
    "zed_body34": ZED_BODY34_KEYPOINTS,
    "zed_body38": ZED_BODY38_KEYPOINTS,
}
"""Every point a tracker may send (the ones the mapping does not use are accepted, unused)."""

UNIT_M: dict[str, float] = {"azure_kinect": 0.001}
"""Metres per unit of a source's positions and velocities (1 where not listed)."""


@dataclass(frozen=True)
class ConfidenceRule:
    """Below ``missing_below``: missing; below ``low_below``: low (see the module notes)."""

    missing_below: float
    low_below: float
    scale: str


CONFIDENCE: dict[str, ConfidenceRule] = {
    "azure_kinect": ConfidenceRule(1.0, 2.0, "K4ABT level 0 none, 1 low, 2 medium, 3 high"),
    "blazepose": ConfidenceRule(0.1, 0.5, "visibility in [0, 1]"),
    "zed_body34": ConfidenceRule(10.0, 50.0, "keypoint confidence in [0, 100]"),
    "zed_body38": ConfidenceRule(10.0, 50.0, "keypoint confidence in [0, 100]"),
}


def joint_confidence(
    source: str,
    table: Mapping[str, tuple[str, ...]],
    joints: tuple[str, ...],
    present: Mapping[str, object],
    confidence: Mapping[str, float] | None,
) -> tuple[np.ndarray, np.ndarray]:
    """``(missing (J,), low (J,))`` of the project's ``joints`` from a message's points
    (``present``) and confidences: a point left out, or below the source's missing level, makes
    its joint missing; below the low level, low. Without confidences nothing is low or
    missing (every point is then required by the message's validation)."""
    J = len(joints)
    missing, low = np.zeros(J, bool), np.zeros(J, bool)
    if confidence is None:
        return missing, low
    rule = CONFIDENCE.get(source)
    for i, j in enumerate(joints):
        for p in table[j]:
            c = confidence.get(p)
            if p not in present or (rule is not None and c is not None and c < rule.missing_below):
                missing[i] = True
            elif rule is not None and c is not None and c < rule.low_below:
                low[i] = True
    return missing, low & ~missing
