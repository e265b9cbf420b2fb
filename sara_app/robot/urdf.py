"""URDF reading for :class:`~sara_app.robot.model.RobotModel`: the joints' acceleration and jerk
limits, and each link's collision primitives as support points for the capsule fit.

A :class:`RobotModel` is built from a URDF whose joints are revolute or prismatic with position,
velocity and effort limits in ``<limit>``, and whose acceleration and jerk limits are in a custom
top-level element that pinocchio and yourdfpy ignore::

    <sara_limits>
      <joint name="joint1" acceleration="15.0" jerk="7500.0"/>   <!-- rad/s^2, rad/s^3 -->
    </sara_limits>

Every URDF link with collision geometry (the base included) carries one capsule,
fitted in the link's frame to that link's primitives (box, cylinder, sphere, mesh, and the common
``<capsule radius length>`` extension). The fit encloses the TRUE primitives, not a tessellation:
each primitive is represented by support points ``p_k`` and one slack ``rho`` such that the
primitive lies in ``conv{p_k} + ball(rho)``:

- box: its 8 corners, ``rho = 0`` (a box is the convex hull of its corners);
- cylinder: ``n`` points on each rim circle, ``rho = r (1 - cos(pi / n))`` (every rim point is
  within the chord sagitta of a chord point, and the cylinder is the hull of its rims);
- sphere: its centre, ``rho = r``; capsule: its two end centres, ``rho = r``;
- mesh: its vertices, ``rho = 0``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from sara_app.errors import RobotModelError

__all__ = ["CYLINDER_RIM_POINTS", "link_supports", "parse_sara_limits"]

CYLINDER_RIM_POINTS = 128
"""Support points per cylinder rim circle; the sagitta slack is ``r (1 - cos(pi / n))``."""


def _floats(text: str | None, n: int, what: str, default: float = 0.0) -> np.ndarray:
    if text is None:
        return np.full(n, default)
    try:
        values = np.array([float(x) for x in text.split()])
    except ValueError:
        raise RobotModelError(f"{what} = {text!r}; expected {n} numbers") from None
    if values.shape != (n,) or not np.all(np.isfinite(values)):
        raise RobotModelError(f"{what} = {text!r}; expected {n} finite numbers")
    return values


def _rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw: ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    cr, sr = np.cos(rpy[0]), np.sin(rpy[0])
    cp, sp = np.cos(rpy[1]), np.sin(rpy[1])
    cy, sy = np.cos(rpy[2]), np.sin(rpy[2])
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def _origin(element: ET.Element, what: str) -> np.ndarray:
    T = np.eye(4)
    origin = element.find("origin")
    if origin is not None:
        T[:3, :3] = _rpy_matrix(_floats(origin.get("rpy"), 3, f"{what} origin rpy"))
        T[:3, 3] = _floats(origin.get("xyz"), 3, f"{what} origin xyz")
    return T


def _positive(element: ET.Element, attr: str, what: str) -> float:
    text = element.get(attr)
    try:
        value = float(text) if text is not None else float("nan")
    except ValueError:
        value = float("nan")
    if not (np.isfinite(value) and value > 0):
        raise RobotModelError(f"{what} {attr} = {text!r}; expected a positive number")
    return value


def _circle(radius: float, z: float, n: int) -> np.ndarray:
    phi = 2.0 * np.pi * np.arange(n) / n
    return np.stack([radius * np.cos(phi), radius * np.sin(phi), np.full(n, z)], axis=1)


def _primitive_support(
    geometry: ET.Element, what: str, urdf_dir: Path
) -> tuple[np.ndarray, float, np.ndarray]:
    """``(support points (k, 3), rho, axis points (m, 3))`` of one primitive, in its own frame.

    The primitive lies in ``conv(support) + ball(rho)``; the axis points only steer the fit.
    """
    shapes = list(geometry)
    if len(shapes) != 1:
        raise RobotModelError(f"{what}: <geometry> has {len(shapes)} children; expected one")
    shape = shapes[0]
    kind = shape.tag
    if kind == "box":
        half = 0.5 * _floats(shape.get("size"), 3, f"{what} box size", default=float("nan"))
        if np.any(half <= 0):
            raise RobotModelError(f"{what} box size = {2 * half}; expected positive sizes")
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        corners = signs * half
        return corners, 0.0, corners
    if kind == "cylinder":
        r = _positive(shape, "radius", f"{what} cylinder")
        h = 0.5 * _positive(shape, "length", f"{what} cylinder")
        n = CYLINDER_RIM_POINTS
        rims = np.concatenate([_circle(r, -h, n), _circle(r, h, n)])
        return rims, r * (1.0 - np.cos(np.pi / n)), rims
    if kind == "sphere":
        r = _positive(shape, "radius", f"{what} sphere")
        return np.zeros((1, 3)), r, np.concatenate([np.eye(3) * r, -np.eye(3) * r])
    if kind == "capsule":
        r = _positive(shape, "radius", f"{what} capsule")
        h = 0.5 * _positive(shape, "length", f"{what} capsule")
        centres = np.array([[0.0, 0.0, -h], [0.0, 0.0, h]])
        tips = np.array([[0.0, 0.0, -h - r], [0.0, 0.0, h + r]])
        return centres, r, np.concatenate([tips, _circle(r, -h, 8), _circle(r, h, 8)])
    if kind == "mesh":
        return _mesh_support(shape, what, urdf_dir)
    raise RobotModelError(
        f"{what}: geometry <{kind}>; valid choices: box, cylinder, sphere, capsule, mesh"
    )


def _mesh_support(
    shape: ET.Element, what: str, urdf_dir: Path
) -> tuple[np.ndarray, float, np.ndarray]:
    import trimesh

    filename = shape.get("filename") or ""
    if filename.startswith("package://"):
        raise RobotModelError(
            f"{what} mesh filename = {filename!r}; package:// paths are not resolved, expected a "
            "path relative to the URDF file or file://"
        )
    path = Path(filename.removeprefix("file://"))
    if not path.is_absolute():
        path = urdf_dir / path
    if not path.is_file():
        raise RobotModelError(f"{what} mesh file {str(path)!r} not found")
    scale = _floats(shape.get("scale"), 3, f"{what} mesh scale", default=1.0)
    try:
        mesh = trimesh.load(str(path), force="mesh")
    except Exception as exc:  # any loader failure means a bad robot description
        raise RobotModelError(f"{what} mesh file {str(path)!r} cannot be read: {exc}") from exc
    if not isinstance(mesh, trimesh.Trimesh):
        raise RobotModelError(f"{what} mesh file {str(path)!r} is not a triangle mesh")
    vertices = np.array(mesh.vertices, dtype=np.float64) * scale
    if vertices.shape[0] == 0:
        raise RobotModelError(f"{what} mesh file {str(path)!r} has no vertices")
    return vertices, 0.0, vertices


def _transform(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    return points @ T[:3, :3].T + T[:3, 3]


def link_supports(
    root: ET.Element, urdf_dir: Path
) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per link with collision geometry: ``(points (K, 3), rho (K,), axis points (M, 3))``."""
    supports: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
    for link in root.findall("link"):
        name = link.get("name", "")
        pts, rho, axis_pts = [], [], []
        for i, collision in enumerate(link.findall("collision")):
            what = f"link {name!r} collision {i}"
            geometry = collision.find("geometry")
            if geometry is None:
                raise RobotModelError(f"{what} has no <geometry>; expected one")
            support, slack, guide = _primitive_support(geometry, what, urdf_dir)
            T = _origin(collision, what)
            pts.append(_transform(T, support))
            rho.append(np.full(len(support), slack))
            axis_pts.append(_transform(T, guide))
        if pts:
            supports[name] = (np.concatenate(pts), np.concatenate(rho), np.concatenate(axis_pts))
    return supports


def check_links(root: ET.Element, path: Path) -> None:
    """Every link a joint moves has an ``<inertial>`` with a positive mass (PFL needs the link
    energies) and, when it has visual geometry, ``<collision>`` geometry (the verification only
    sees the capsules fitted to it); :class:`RobotModelError` naming the link and element."""
    moved = {j.find("child").get("link", "") for j in root.findall("joint")  # type: ignore[union-attr]
             if j.get("type") != "fixed" and j.find("child") is not None}  # fmt: skip
    if not any(link.find("collision") is not None for link in root.findall("link")):
        raise RobotModelError(
            f"URDF {path} has no <collision> geometry on any link; expected collision "
            "primitives or meshes on every moving link (their capsules are what is verified)"
        )
    for link in root.findall("link"):
        name = link.get("name", "")
        if name not in moved:
            continue
        inertial = link.find("inertial")
        mass = None if inertial is None else inertial.find("mass")
        if inertial is None or mass is None:
            raise RobotModelError(
                f"link {name!r} in {path} has no <inertial> with a <mass>; expected the link's "
                "mass, centre of mass and inertia (PFL computes link energies from them)"
            )
        _positive(mass, "value", f"link {name!r} <inertial><mass>")
        if link.find("visual") is not None and link.find("collision") is None:
            raise RobotModelError(
                f"link {name!r} in {path} has <visual> but no <collision> geometry; expected "
                "<collision> (the verification sees only the capsule fitted to it)"
            )


def parse_sara_limits(
    root: ET.Element,
    joint_names: tuple[str, ...],
    path: Path,
    given: Mapping[str, tuple[float, float]] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Acceleration and jerk limits ``(n_dof,)`` each from ``<sara_limits>``, completed or
    overridden by ``given`` (joint name -> (acceleration, jerk), e.g. a scenario's
    ``robot.joint_limits`` for a URDF that has no ``<sara_limits>``)."""
    entries: dict[str, tuple[float, float]] = {}
    for block in root.findall("sara_limits"):
        for joint in block.findall("joint"):
            name = joint.get("name", "")
            if name not in joint_names:
                raise RobotModelError(
                    f"<sara_limits> in {path} names joint {name!r}, which is not an actuated "
                    f"joint; valid choices: {', '.join(joint_names)}"
                )
            if name in entries:
                raise RobotModelError(f"<sara_limits> in {path} lists joint {name!r} twice")
            what = f"<sara_limits> joint {name!r} in {path}:"
            entries[name] = (
                _positive(joint, "acceleration", what),
                _positive(joint, "jerk", what),
            )
    for name, (acc, jerk) in (given or {}).items():
        if name not in joint_names:
            raise RobotModelError(
                f"joint limits given for {name!r}, which is not an actuated joint of {path}; "
                f"valid choices: {', '.join(joint_names)}"
            )
        if not (np.isfinite(acc) and acc > 0 and np.isfinite(jerk) and jerk > 0):
            raise RobotModelError(
                f"joint {name!r} limits acceleration {acc}, jerk {jerk}; expected positive values"
            )
        entries[name] = (float(acc), float(jerk))
    missing = [name for name in joint_names if name not in entries]
    if missing:
        raise RobotModelError(
            f"joint {missing[0]!r} has no acceleration/jerk limits in {path}"
            + (f" (nor {', '.join(repr(m) for m in missing[1:])})" if len(missing) > 1 else "")
            + f'; expected <sara_limits><joint name="{missing[0]}" acceleration="..." '
            'jerk="..."/></sara_limits> inside <robot>, or the scenario\'s robot.joint_limits '
            f'{{"{missing[0]}": {{"acceleration_rad_s2": ..., "jerk_rad_s3": ...}}}}'
        )
    a = np.array([entries[name][0] for name in joint_names])
    j = np.array([entries[name][1] for name in joint_names])
    return a, j
