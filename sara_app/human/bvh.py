"""BVH motion capture (Biovision hierarchy) to a :class:`~sara_app.human.recording.Recording` of
the project's joints.

Parsing and forward kinematics: ``pybvh`` (MIT, maintained; numpy only), whose node positions are
the origins of the BVH joints and their end sites in the file's units and axes, one frame per
row. What it does not know and this module decides:

**Skeletons.** A joint map per known skeleton, chosen by the joint names:

- ``cmu``: the CMU ASF/AMC skeleton converted to BVH (``Hips``, ``LeftUpLeg``, ``Spine1``,
  ``Neck1``, ...; CMU subject 62). The points are those of :mod:`sara_app.human.cmu`'s map:
  head = midpoint of the ``Head`` joint (skull base) and its end site (top of the head), neck =
  ``Neck`` (thorax end), pelvis = ``Hips``, shoulder = ``LeftArm`` (clavicle end), elbow =
  ``LeftForeArm``, wrist = ``LeftHand`` (radius end), hip = ``LeftUpLeg``, knee = ``LeftLeg``,
  ankle = ``LeftFoot``. A ``full`` recording.
- ``vicon_upper``: the TUM table-side recordings' Vicon skeleton (``hip``, ``torso``, ``neck``,
  ``head``, ``left_collar``, ``left_upper_arm``, ``left_forearm``, ``left_hand``, ...), upper
  body only: an ``upper`` recording (treated like ``sara_upper``: the legs are not measured).
  head = midpoint of ``neck`` and ``head`` (the ``head`` joint lies at the top of the head, 0.4 m
  above the neck base: the midpoint is the head's centre), neck = ``neck`` (where the collars
  start, at shoulder height), pelvis = ``hip``, shoulder = ``left_upper_arm``, elbow =
  ``left_forearm``, wrist = ``left_hand``.

**Units**, established from the data unless given: the median upper-arm length (shoulder to
elbow, both arms, every frame) in file units, and of the candidate units (:data:`UNITS`) the one
that makes it closest to 0.30 m; refused unless that length is within 0.20-0.45 m (adult upper
arms measure about 0.26-0.37 m). CMU subject 62 comes out in CMU's ASF unit (0.0254 / 0.45 m),
the TUM recordings in millimetres.

**Up axis**, established from the data unless given: of +-x, +-y, +-z the axis best aligned with
the pelvis-to-neck direction of the skeleton's rest pose (the hierarchy's offsets: a person
standing upright), checked against the motion (the median pelvis-to-neck direction must point
up too; people at a table lean forward by up to 55 degrees in the TUM recordings, so the motion
alone does not decide). The recording is turned so that this axis becomes +z by a proper
rotation (lengths and handedness kept: left stays left); for y up that is the CMU convention
``(x, y, z)_world = (x, -z, y)_file``. The height of the floor is not in an upper-body file:
where the recording stands is the scenario's (a recording's offset).

**Handedness**, established from the rest pose where it can be: a person's head sits in front of
the neck's base, so with the head's horizontal offset from the neck in the rest pose as
"forward", the left shoulder must lie on the left of (up, forward). Where it lies on the right
the file's axes are left-handed (the TUM recordings: head 0.10-0.12 m forward, left shoulder on
the right) and the recording is mirrored (world x negated) so that left stays left. Where the
offset is under 2 cm (a T-pose with the head upright: CMU) the file is taken as right-handed,
the BVH convention, and the source says so.

**A T-pose first frame** (the CMU conversions start with one) is no motion: a first frame whose
forearms both lie within 20 degrees of horizontal while the next frame's do not is dropped (and
said in the recording's source).

Frame ``i`` (after a dropped T-pose) is at ``i * frame_time`` seconds.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from sara_app.errors import InputError, RecordingError
from sara_app.human.recording import Recording, check_frame_interval
from sara_app.human.skeleton import FULL_JOINTS, UPPER_JOINTS

UNITS: dict[str, float] = {
    "m": 1.0,
    "cm": 0.01,
    "mm": 0.001,
    "inch": 0.0254,
    "cmu": 0.0254 / 0.45,
}
"""Candidate length units (metres per file unit); ``cmu`` is CMU's ASF unit."""
UPPER_ARM_M = (0.20, 0.30, 0.45)
"""Plausible upper-arm lengths (min, typical, max), m: the unit check."""
AXES = ("+x", "-x", "+y", "-y", "+z", "-z")
T_POSE_DEG = 20.0

# project joint -> the BVH points it is the mean of (a joint's origin, or "EndSite<joint>")
SKELETONS: dict[str, tuple[str, dict[str, tuple[str, ...]]]] = {
    "cmu": (
        "full",
        {
            "head": ("Head", "EndSiteHead"),
            "neck": ("Neck",),
            "pelvis": ("Hips",),
            "l_shoulder": ("LeftArm",),
            "r_shoulder": ("RightArm",),
            "l_elbow": ("LeftForeArm",),
            "r_elbow": ("RightForeArm",),
            "l_wrist": ("LeftHand",),
            "r_wrist": ("RightHand",),
            "l_hip": ("LeftUpLeg",),
            "r_hip": ("RightUpLeg",),
            "l_knee": ("LeftLeg",),
            "r_knee": ("RightLeg",),
            "l_ankle": ("LeftFoot",),
            "r_ankle": ("RightFoot",),
        },
    ),
    "vicon_upper": (
        "upper",
        {
            "head": ("neck", "head"),
            "neck": ("neck",),
            "pelvis": ("hip",),
            "l_shoulder": ("left_upper_arm",),
            "r_shoulder": ("right_upper_arm",),
            "l_elbow": ("left_forearm",),
            "r_elbow": ("right_forearm",),
            "l_wrist": ("left_hand",),
            "r_wrist": ("right_hand",),
        },
    ),
}


def _read(path: Path) -> tuple[list[str], np.ndarray, np.ndarray, float]:
    """Node names, node positions ``(T, N, 3)`` and in the rest pose ``(N, 3)`` (file units and
    axes), and the frame time."""
    import pybvh  # imported on use: a BVH file is read by a few commands only

    try:
        b = pybvh.read_bvh_file(path, warn_on_world_up_disagreement=False)
        with np.errstate(invalid="ignore", over="ignore"):  # a non-finite channel: said below
            pos = np.asarray(b.node_positions(), dtype=float)
            rest = np.asarray(b.rest_pose_positions(), dtype=float)
    except (OSError, ValueError, IndexError, KeyError) as exc:
        raise RecordingError(f"cannot read BVH file {str(path)!r}: {exc}") from None
    names = [n.name for n in b.nodes]
    if pos.ndim != 3 or pos.shape[1:] != (len(names), 3) or pos.shape[0] < 2:
        raise RecordingError(f"BVH file {path.name!r}: expected at least two frames of motion")
    bad = ~np.isfinite(pos).all(axis=2)  # (T, N): a nan or inf channel, or an overflow
    if bad.any():
        f, n = (int(i) for i in np.argwhere(bad)[0])
        raise RecordingError(
            f"BVH file {path.name!r}: frame {f} puts {names[n]!r} at a non-finite position "
            f"({int(bad.any(axis=1).sum())} of {len(bad)} frames have one); expected finite "
            "channel values"
        )
    dt = float(b.frame_time)
    if not (math.isfinite(dt) and dt > 0):
        raise RecordingError(f"BVH file {path.name!r}: frame time {dt!r}; expected > 0 s")
    check_frame_interval(dt, f"BVH file {path.name!r}", "its Frame Time")
    return names, pos, rest, dt


def which_skeleton(names: list[str]) -> str:
    """The known skeleton whose points the file has (raises naming what is missing)."""
    missing = {}
    for key, (_, points) in SKELETONS.items():
        need = {p for pts in points.values() for p in pts}
        missing[key] = sorted(need - set(names))
        if not missing[key]:
            return key
    raise RecordingError(
        f"BVH skeleton with joints {names[:12]}... is none of the known ones "
        f"({', '.join(SKELETONS)}); missing: "
        + "; ".join(f"{k}: {v[:6]}" for k, v in missing.items())
    )


def _unit(upper_arm: float, path: Path) -> str:
    lo, typ, hi = UPPER_ARM_M
    best = min(UNITS, key=lambda u: abs(math.log(upper_arm * UNITS[u] / typ)))
    if not lo <= upper_arm * UNITS[best] <= hi:
        raise RecordingError(
            f"BVH file {path.name!r}: no unit makes the upper arm ({upper_arm:.4g} file units) "
            f"{lo}-{hi} m long; give the unit ({', '.join(UNITS)})"
        )
    return best


def _up_axis(rest_up: np.ndarray, moving_up: np.ndarray, path: Path) -> str:
    """The axis of the rest pose's pelvis-to-neck vector ``rest_up (3,)``; the motion's
    ``moving_up (T, 3)`` must agree (median component along it > 0)."""
    k = int(np.argmax(np.abs(rest_up)))
    axis = ("+" if rest_up[k] > 0 else "-") + "xyz"[k]
    if not np.median(moving_up[:, k]) * np.sign(rest_up[k]) > 0:
        raise RecordingError(
            f"BVH file {path.name!r}: the rest pose stands along {axis} but the motion's "
            f"pelvis-to-neck points the other way; give the up axis ({', '.join(AXES)})"
        )
    return axis


def to_z_up(axis: str) -> np.ndarray:
    """``R (3, 3)``, det +1, that turns file axis ``axis`` (one of :data:`AXES`) into +z."""
    if axis not in AXES:
        raise InputError(f"up axis {axis!r}; valid: {', '.join(AXES)}")
    k, s = "xyz".index(axis[1]), 1.0 if axis[0] == "+" else -1.0
    up = np.zeros(3)
    up[k] = s
    x = np.zeros(3)
    x[1 if k == 0 else 0] = 1.0  # file x stays world x (file y when x is up)
    return np.stack([x, np.cross(up, x), up])  # rows: world x, y = z cross x, z


HEAD_FORWARD_MIN_M = 0.02
HANDEDNESS = {
    "right": "right-handed axes (from the rest pose)",
    "left": "left-handed axes, mirrored (from the rest pose)",
    "assumed": "right-handed axes (assumed: the rest pose's head is upright)",
}


def _handedness(rest: list[np.ndarray]) -> str:
    """``right``, ``left`` or ``assumed`` from the rest pose's neck, head and shoulders (z up,
    metres; see the module notes)."""
    neck, head, left, right = rest
    forward = head - neck
    forward[2] = 0.0
    if np.linalg.norm(forward) < HEAD_FORWARD_MIN_M:
        return "assumed"
    return "right" if np.cross([0.0, 0.0, 1.0], forward) @ (left - right) > 0 else "left"


def _is_t_pose(pos: np.ndarray, idx: dict[str, int], R: np.ndarray) -> bool:
    """Both forearms within ``T_POSE_DEG`` of horizontal in frame 0, not in frame 1."""

    def flat(i: int) -> bool:
        ok = True
        for s in "lr":
            fore = (pos[i, idx[f"{s}_wrist"]] - pos[i, idx[f"{s}_elbow"]]) @ R.T
            n = float(np.linalg.norm(fore))
            ok &= n > 0 and abs(fore[2]) / n < math.sin(math.radians(T_POSE_DEG))
        return ok

    return len(pos) > 2 and flat(0) and not flat(1)


def load_bvh(
    path: str | os.PathLike[str],
    *,
    unit: str | None = None,
    up: str | None = None,
    name: str | None = None,
) -> Recording:
    """A BVH file as a recording of the project's joints (see the module notes): metres,
    world frame z up. ``unit`` (one of :data:`UNITS`) and ``up`` (one of :data:`AXES`) override
    what the data establish; ``name`` defaults to the file stem."""
    p = Path(path)
    if unit is not None and unit not in UNITS:
        raise InputError(f"BVH unit {unit!r}; valid: {', '.join(UNITS)}")
    names, raw, rest, dt = _read(p)
    key = which_skeleton(names)
    kind, points = SKELETONS[key]
    node = {n: i for i, n in enumerate(names)}
    joints = FULL_JOINTS if kind == "full" else UPPER_JOINTS

    def at(x: np.ndarray, joint: str) -> np.ndarray:
        return x[..., [node[q] for q in points[joint]], :].mean(axis=-2)

    pos = np.stack([at(raw, j) for j in joints], axis=1)
    idx = {j: i for i, j in enumerate(joints)}
    arms = [pos[:, idx[f"{s}_elbow"]] - pos[:, idx[f"{s}_shoulder"]] for s in "lr"]
    upper_arm = float(np.median(np.linalg.norm(np.concatenate(arms), axis=-1)))
    unit = unit or _unit(upper_arm, p)
    moving = pos[:, idx["neck"]] - pos[:, idx["pelvis"]]
    up = up or _up_axis(at(rest, "neck") - at(rest, "pelvis"), moving, p)
    R = to_z_up(up)
    dropped = _is_t_pose(pos, idx, R)
    pos = pos[1:] if dropped else pos
    hand = _handedness([(at(rest, j) @ R.T) * UNITS[unit] for j in ("neck", "head",
                        "l_shoulder", "r_shoulder")])  # fmt: skip
    if hand == "left":
        R = np.diag([-1.0, 1.0, 1.0]) @ R  # mirrored: left stays left
    world = (pos @ R.T) * UNITS[unit]
    return Recording(
        name=name if name is not None else p.stem,
        kind=kind,
        times_s=np.arange(len(world)) * dt,
        positions_m=world,
        source=(
            f"BVH {p.name} ({key} skeleton), {1.0 / dt:g} Hz, unit {unit} "
            f"({UNITS[unit]:g} m), up {up}, {HANDEDNESS[hand]}"
            f"{', T-pose frame 0 dropped' if dropped else ''}"
        ),
    )
