"""The project's human skeleton: named joints, body parts, and mappings from common sources.

Two skeleton kinds are supported:
- ``full``: 15 joints and the 14 body parts of Schepp et al. 2022 Fig. 3a (head, torso, upper and
lower
  arms, hands, thighs, shins, feet);
- ``upper``: 9 joints and the 8 upper-body parts (head, torso, arms, hands).

A body part is a capsule between two joints (``joint_a != joint_b``) or a ball at one joint
(``joint_a == joint_b``; head, hands, feet are balls as in Schepp et al. 2022 Sec. II-B). The
thickness of a body part is a *diameter*; half of it is added to the reachable-set radius.

Source mappings turn a dictionary of named points from a tracking system into the project's
``(J, 3)`` array, deriving virtual joints (e.g. the neck as the middle of the shoulders) as means
of measured points, whose error bound is the same delta_y as that of the measured points.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from sara_app.errors import InputError, UnknownNameError
from sara_app.human.trackers import TRACKER_SOURCES, UNIT_M

FULL_JOINTS: tuple[str, ...] = (
    "head",
    "neck",
    "pelvis",
    "l_shoulder",
    "r_shoulder",
    "l_elbow",
    "r_elbow",
    "l_wrist",
    "r_wrist",
    "l_hip",
    "r_hip",
    "l_knee",
    "r_knee",
    "l_ankle",
    "r_ankle",
)
UPPER_JOINTS: tuple[str, ...] = FULL_JOINTS[:9]

# body part -> (joint_a, joint_b); a ball when both are the same joint.
FULL_BODY_PARTS: dict[str, tuple[str, str]] = {
    "head": ("head", "head"),
    "torso": ("neck", "pelvis"),
    "l_upper_arm": ("l_shoulder", "l_elbow"),
    "r_upper_arm": ("r_shoulder", "r_elbow"),
    "l_lower_arm": ("l_elbow", "l_wrist"),
    "r_lower_arm": ("r_elbow", "r_wrist"),
    "l_hand": ("l_wrist", "l_wrist"),
    "r_hand": ("r_wrist", "r_wrist"),
    "l_thigh": ("l_hip", "l_knee"),
    "r_thigh": ("r_hip", "r_knee"),
    "l_shin": ("l_knee", "l_ankle"),
    "r_shin": ("r_knee", "r_ankle"),
    "l_foot": ("l_ankle", "l_ankle"),
    "r_foot": ("r_ankle", "r_ankle"),
}
UPPER_BODY_PARTS: dict[str, tuple[str, str]] = {
    k: v for k, v in FULL_BODY_PARTS.items() if v[0] in UPPER_JOINTS and v[1] in UPPER_JOINTS
}

# Limbs for the position model R_POS (Schepp et al. 2022 Sec. II-B): root joint and the chain to the
# tip; the tip's body part (hand or foot) is the ball whose thickness is added.
LIMBS: dict[str, tuple[tuple[str, ...], str]] = {
    "l_arm": (("l_shoulder", "l_elbow", "l_wrist"), "l_hand"),
    "r_arm": (("r_shoulder", "r_elbow", "r_wrist"), "r_hand"),
    "l_leg": (("l_hip", "l_knee", "l_ankle"), "l_foot"),
    "r_leg": (("r_hip", "r_knee", "r_ankle"), "r_foot"),
}

KINDS = ("full", "upper")


@dataclass(frozen=True)
class Skeleton:
    """Joint and body-part index tables of one skeleton kind, built once.

    ``part_joints`` has shape ``(P, 2)``: the indices of each body part's two end joints.
    """

    kind: str
    joints: tuple[str, ...]
    parts: tuple[str, ...]
    part_joints: np.ndarray  # (P, 2) int
    limbs: tuple[str, ...]
    limb_chains: tuple[tuple[int, ...], ...]
    limb_tip_parts: tuple[int, ...]

    @property
    def n_joints(self) -> int:
        return len(self.joints)

    @property
    def n_parts(self) -> int:
        return len(self.parts)

    def joint_index(self, name: str) -> int:
        try:
            return self.joints.index(name)
        except ValueError:
            raise UnknownNameError(
                f"joint of the {self.kind!r} skeleton", name, self.joints
            ) from None

    def part_index(self, name: str) -> int:
        try:
            return self.parts.index(name)
        except ValueError:
            raise UnknownNameError(
                f"body part of the {self.kind!r} skeleton", name, self.parts
            ) from None

    def parts_of_joint(self, joint: str) -> tuple[str, ...]:
        j = self.joint_index(joint)
        return tuple(p for p, (a, b) in zip(self.parts, self.part_joints) if j in (a, b))


def _build(kind: str) -> Skeleton:
    joints = FULL_JOINTS if kind == "full" else UPPER_JOINTS
    table = FULL_BODY_PARTS if kind == "full" else UPPER_BODY_PARTS
    parts = tuple(table)
    part_joints = np.array([[joints.index(a), joints.index(b)] for a, b in table.values()])
    limbs = tuple(k for k, (chain, _) in LIMBS.items() if all(j in joints for j in chain))
    chains = tuple(tuple(joints.index(j) for j in LIMBS[k][0]) for k in limbs)
    tips = tuple(parts.index(LIMBS[k][1]) for k in limbs)
    return Skeleton(kind, joints, parts, part_joints, limbs, chains, tips)


_SKELETONS = {k: _build(k) for k in KINDS}


def skeleton(kind: str) -> Skeleton:
    """The skeleton of ``kind`` (``'full'`` or ``'upper'``)."""
    try:
        return _SKELETONS[kind]
    except KeyError:
        raise UnknownNameError("skeleton kind", kind, KINDS) from None


# --- sources -------------------------------------------------------------------------------

# Each source maps a project joint to one or more source point names; several names mean the
# joint is virtual: the mean of those points.
COCO17_NAMES: tuple[str, ...] = (
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
)

SOURCES: dict[str, tuple[str, dict[str, tuple[str, ...]]]] = {
    # A 17-keypoint COCO-style body: no neck, pelvis or head centre, so they are virtual.
    "coco17": (
        "full",
        {
            "head": ("left_ear", "right_ear"),
            "neck": ("left_shoulder", "right_shoulder"),
            "pelvis": ("left_hip", "right_hip"),
            **{
                f"{s[0]}_{j}": (f"{s}_{j}",)
                for s in ("left", "right")
                for j in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")
            },
        },
    ),
    # SaRA's upper-body marker set (Schepp et al. 2022 Sec. IV-A: H, N, LS, LE, LW, RS, RE, RW) plus
    # two virtual torso points: the mid-shoulder point and the torso base TB (lower spine marker).
    "sara10": (
        "upper",
        {
            "head": ("H",),
            "neck": ("N",),
            "pelvis": ("TB",),
            "l_shoulder": ("LS",),
            "r_shoulder": ("RS",),
            "l_elbow": ("LE",),
            "r_elbow": ("RE",),
            "l_wrist": ("LW",),
            "r_wrist": ("RW",),
        },
    ),
    # The project's own names, for CSV files and Zenoh clients that already use them.
    "sara_full": ("full", {j: (j,) for j in FULL_JOINTS}),
    "sara_upper": ("upper", {j: (j,) for j in UPPER_JOINTS}),
    # Azure Kinect, BlazePose, ZED BODY_34 (units and confidence: sara_app.human.trackers).
    **TRACKER_SOURCES,
}


def full_body(y_m: np.ndarray, v_mps: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """``(J, 3)`` positions and velocities of either kind as the ``full`` skeleton's ``(15, 3)``:
    an upper-body measurement gets its leg joints at the pelvis, at rest. These placeholders
    are not measurements: a caller must cover the legs by other means (or not verify)."""
    if y_m.shape[0] == len(FULL_JOINTS):
        return y_m, v_mps
    pelvis = UPPER_JOINTS.index("pelvis")
    n_legs = len(FULL_JOINTS) - len(UPPER_JOINTS)
    y = np.concatenate([y_m, np.repeat(y_m[pelvis : pelvis + 1], n_legs, axis=0)])
    if v_mps is None:
        return y, None
    return y, np.concatenate([v_mps, np.zeros((n_legs, 3))])


def source_kind(source: str) -> str:
    """The skeleton kind that ``source`` maps to."""
    try:
        return SOURCES[source][0]
    except KeyError:
        raise UnknownNameError("skeleton source", source, SOURCES) from None


def from_source(source: str, points: Mapping[str, object]) -> np.ndarray:
    """Map named source points (each a 3-vector in the source's unit, metres but for
    :data:`~sara_app.human.trackers.UNIT_M`) to the ``(J, 3)`` joint array in metres.

    Raises InputError naming every missing point and every non-finite one. Extra names are
    ignored: tracking systems often send more points than the model needs.
    """
    kind = source_kind(source)
    table = SOURCES[source][1]
    sk = skeleton(kind)
    needed = sorted({n for j in sk.joints for n in table[j]})
    missing = [n for n in needed if n not in points]
    if missing:
        raise InputError(f"source {source!r} is missing points {missing}; it needs {needed}")
    out = np.empty((sk.n_joints, 3))
    for i, j in enumerate(sk.joints):
        pts = [np.asarray(points[n], dtype=float) for n in table[j]]
        for n, p in zip(table[j], pts):
            if p.shape != (3,):
                raise InputError(f"point {n!r} has shape {p.shape}; expected (3,)")
            if not np.all(np.isfinite(p)):
                raise InputError(f"point {n!r} is not finite: {p.tolist()}")
        out[i] = np.mean(pts, axis=0)
    return out * UNIT_M.get(source, 1.0)
