"""The cell's messages to and from ROS 2 messages (plain dicts in the layout of
:mod:`sara_app.ros2.interfaces`, encoded by the CDR library).

- the command -> ``sensor_msgs/JointState`` (the set point: names, positions, velocities);
- a measured ``sensor_msgs/JointState`` -> the cell's robot state: joints matched BY NAME (any
  order, extra joints ignored); a missing joint, a missing velocity or a non-finite value is an
  :class:`InputError` (the sample is dropped and counted: the cell then has no fresh state and
  its usual freshness rule holds the robot);
- the occupancy -> ``visualization_msgs/MarkerArray``: every capsule as a cylinder and two
  spheres (RViz and Foxglove have no capsule), first a DELETEALL so that capsules of an older
  message never linger; the robot's capsules in the verdict colour, each person's effective set
  (or, without one, every model's set) in one colour per person; a set's capsules that are cut
  at a height bound (``below_m``: legs an upper-body tracker does not measure) as one triangle
  list, the capsules' parts below their cuts
  (:func:`~sara_app.geometry.capsule_mesh.cut_capsule_mesh`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from sara_app.bus.messages import OccupancyMsg, RobotCommandMsg
from sara_app.errors import InputError
from sara_app.geometry.capsule_mesh import cut_capsule_mesh
from sara_app.geometry.shapes import quat_z_to
from sara_app.ros2.interfaces import (
    MARKER_ADD,
    MARKER_CYLINDER,
    MARKER_DELETEALL,
    MARKER_SPHERE,
    MARKER_TRIANGLE_LIST,
)

VERIFIED_RGBA = (0.12, 0.75, 0.24, 0.35)
UNVERIFIED_RGBA = (0.88, 0.12, 0.12, 0.35)
HUMAN_RGBA = (0.96, 0.59, 0.43, 0.3)
HUMAN_SET = "effective"
IDENTITY = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


def header(stamp_s: float, frame_id: str) -> dict[str, Any]:
    sec = int(np.floor(stamp_s))
    return {"stamp": {"sec": sec, "nanosec": int(round((stamp_s - sec) * 1e9)) % 1_000_000_000},
            "frame_id": frame_id}  # fmt: skip


def command_joint_state(
    cmd: RobotCommandMsg, names: Sequence[str], frame_id: str
) -> dict[str, Any]:
    if len(cmd.q) != len(names):
        raise InputError(f"command has {len(cmd.q)} joints; the robot has {len(names)}")
    return {"header": header(cmd.stamp_s, frame_id), "name": list(names),
            "position": list(cmd.q), "velocity": list(cmd.q_dot), "effort": []}  # fmt: skip


def robot_state(js: Any, names: Sequence[str]) -> tuple[list[float], list[float], float]:
    """``(q, q_dot, stamp_s)`` in the robot's joint order from a decoded JointState."""
    given = list(js.name)
    missing = [n for n in names if n not in given]
    if missing:
        raise InputError(f"JointState lacks joints {missing}; the robot's are {list(names)}")
    if len(js.position) != len(given) or len(js.velocity) != len(given):
        raise InputError(
            f"JointState has {len(given)} names, {len(js.position)} positions and "
            f"{len(js.velocity)} velocities; expected positions and velocities for every name"
        )
    idx = [given.index(n) for n in names]
    q = np.asarray(js.position, float)[idx]
    qd = np.asarray(js.velocity, float)[idx]
    if not (np.isfinite(q).all() and np.isfinite(qd).all()):
        raise InputError("JointState has non-finite positions or velocities")
    stamp = float(js.header.stamp.sec) + 1e-9 * float(js.header.stamp.nanosec)
    return q.tolist(), qd.tolist(), stamp


def _capsule_markers(
    ends: np.ndarray, radius: np.ndarray, ns: str, rgba: tuple[float, ...], base: dict[str, Any]
) -> list[dict[str, Any]]:
    """Cylinder + two spheres per capsule ``ends (C, 2, 3)``, ``radius (C,)``; non-finite ones
    are left out."""
    ok = np.isfinite(ends).all(axis=(1, 2)) & np.isfinite(radius) & (radius >= 0)
    ends, radius = ends[ok], radius[ok]
    axis = ends[:, 1] - ends[:, 0]
    length = np.linalg.norm(axis, axis=1)
    d = np.where(length[:, None] > 1e-12, axis / np.maximum(length, 1e-300)[:, None],
                 [0.0, 0.0, 1.0])  # fmt: skip
    q = quat_z_to(d)  # (w, x, y, z)
    mid = ends.mean(axis=1)
    color = dict(zip("rgba", rgba, strict=True))
    out = []
    for c in range(len(radius)):
        r2 = 2.0 * float(radius[c])
        w, x, y, z = (float(v) for v in q[c])
        out.append({**base, "ns": ns, "id": 3 * c, "type": MARKER_CYLINDER, "color": color,
                    "pose": {"position": dict(zip("xyz", mid[c].tolist(), strict=True)),
                             "orientation": {"x": x, "y": y, "z": z, "w": w}},
                    "scale": {"x": r2, "y": r2, "z": float(length[c])}})  # fmt: skip
        for e in (0, 1):
            at = dict(zip("xyz", ends[c, e].tolist(), strict=True))
            out.append({**base, "ns": ns, "id": 3 * c + 1 + e, "type": MARKER_SPHERE,
                        "color": color, "scale": {"x": r2, "y": r2, "z": r2},
                        "pose": {"position": at, "orientation": IDENTITY}})  # fmt: skip
    return out


def _cut_marker(
    ends: np.ndarray, radius: np.ndarray, below_m: np.ndarray, ns: str,
    rgba: tuple[float, ...], base: dict[str, Any],
) -> list[dict[str, Any]]:  # fmt: skip
    """One TRIANGLE_LIST of capsules ``ends (C, 2, 3)``, ``radius (C,)`` cut at ``below_m
    (C,)`` (none when nothing is left of them)."""
    v, f = cut_capsule_mesh(ends, radius, below_m)
    if not f.shape[0]:
        return []
    points = [dict(zip("xyz", p, strict=True)) for p in v[f].reshape(-1, 3).tolist()]
    origin = {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": IDENTITY}
    return [{**base, "ns": ns, "id": 0, "type": MARKER_TRIANGLE_LIST, "points": points,
             "color": dict(zip("rgba", rgba, strict=True)), "pose": origin,
             "scale": {"x": 1.0, "y": 1.0, "z": 1.0}}]  # fmt: skip


def occupancy_markers(occ: OccupancyMsg, frame_id: str) -> dict[str, Any]:
    """The MarkerArray of one occupancy message."""
    base = {"header": header(occ.stamp_s, frame_id), "action": MARKER_ADD}
    markers: list[dict[str, Any]] = [{**base, "ns": "", "id": 0, "action": MARKER_DELETEALL}]
    if occ.robot is not None:
        ends, radius = occ.robot.capsules.arrays()
        rgba = VERIFIED_RGBA if occ.robot.verified else UNVERIFIED_RGBA
        markers += _capsule_markers(ends, radius, "sara/robot", rgba, base)
    for h in occ.humans:
        sets = [HUMAN_SET] if HUMAN_SET in h.models else sorted(h.models)
        for name in sets:
            ends, radius = h.models[name].arrays()
            below = h.models[name].cuts()
            cut = np.isfinite(below)
            ns = f"sara/human/{h.id}/{name}"
            markers += _capsule_markers(ends[~cut], radius[~cut], ns, HUMAN_RGBA, base)
            if cut.any():
                markers += _cut_marker(ends[cut], radius[cut], below[cut], f"{ns}/cut",
                                       HUMAN_RGBA, base)  # fmt: skip
    return {"markers": markers}
