"""Robot model: pinocchio kinematics and dynamics plus link capsules fitted once from the URDF.

A :class:`RobotModel` is built from a URDF whose joints are revolute or prismatic with position,
velocity and effort limits in ``<limit>``, and whose acceleration and jerk limits are in a custom
top-level element that pinocchio and yourdfpy ignore::

    <sara_limits>
      <joint name="joint1" acceleration="15.0" jerk="7500.0"/>   <!-- rad/s^2, rad/s^3 -->
    </sara_limits>

Link capsules. Every URDF link with collision geometry (the base included) carries one capsule,
fitted in the link's frame to that link's primitives (box, cylinder, sphere, mesh, and the common
``<capsule radius length>`` extension). The fit encloses the TRUE primitives, not a tessellation:
each primitive is represented by support points ``p_k`` and one slack ``rho`` such that the
primitive lies in ``conv{p_k} + ball(rho)``:

- box: its 8 corners, ``rho = 0`` (a box is the convex hull of its corners);
- cylinder: ``n`` points on each rim circle, ``rho = r (1 - cos(pi / n))`` (every rim point is
  within the chord sagitta of a chord point, and the cylinder is the hull of its rims);
- sphere: its centre, ``rho = r``; capsule: its two end centres, ``rho = r``;
- mesh: its vertices, ``rho = 0``.

A capsule is convex and its distance function is convex, so if every ``p_k`` is within
``R - rho`` of the segment, the whole primitive is within ``R``. The radius is always recomputed
as ``max_k (dist(p_k, segment) + rho_k)``; the optimisation only moves the segment.

Fit: principal axes of the support points; for each candidate axis the two end insets are
chosen on a grid (the radius as a function of the insets separates into a function of each end,
so this is a pair of 1-D problems) to minimise the capsule volume; the best candidate is polished
by Nelder-Mead over both end points (radius recomputed for every trial). The fitted capsules are
cached per URDF file; per configuration only the end points are transformed.

Frames and conventions: capsule ends ``(L, 2, 3)`` and radii ``(L,)`` as in
:mod:`sara_app.geometry`; world frame = ``T_world_base @`` pinocchio's frame placements (the
pinocchio "universe" is the URDF root link's frame). Angles in rad, lengths in m.

Not thread-safe: a model owns one ``pinocchio.Data``; use one model per thread.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin
from scipy.optimize import minimize

from sara_app.errors import InputError, ParameterError, RobotModelError, UnknownNameError
from sara_app.geometry import point_segment_distance

ROBOT_NAMES: tuple[str, ...] = ("panda", "ur5e")
"""Robots shipped in the repository's ``urdf/`` folder (``<name>.urdf``)."""

CYLINDER_RIM_POINTS = 128
"""Support points per cylinder rim circle; the sagitta slack is ``r (1 - cos(pi / n))``."""

ENCLOSURE_SLACK_M = 1e-9
"""Added to every fitted radius to absorb floating-point rounding in the enclosure."""

_GRID = 129


@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits, arrays of shape ``(n_dof,)`` in joint order (rad or m based units).

    ``tau_max`` (effort, N m or N) is optional for hand-built limit sets.
    """

    q_min: np.ndarray
    q_max: np.ndarray
    v_max: np.ndarray
    a_max: np.ndarray
    j_max: np.ndarray
    tau_max: np.ndarray | None = None

    def __post_init__(self) -> None:
        arrays = {
            "q_min": self.q_min,
            "q_max": self.q_max,
            "v_max": self.v_max,
            "a_max": self.a_max,
            "j_max": self.j_max,
        }
        if self.tau_max is not None:
            arrays["tau_max"] = self.tau_max
        n = np.shape(self.q_min)
        for key, value in arrays.items():
            arr = np.array(value, dtype=float)
            if arr.ndim != 1 or arr.shape != n:
                raise RobotModelError(
                    f"joint limit {key} has shape {arr.shape}; expected {n} like q_min"
                )
            if not np.all(np.isfinite(arr)):
                raise RobotModelError(f"joint limit {key} = {arr.tolist()} is not finite")
            arr.flags.writeable = False
            object.__setattr__(self, key, arr)
        bad = np.flatnonzero(~(self.q_min < self.q_max))
        if bad.size:
            i = int(bad[0])
            raise RobotModelError(
                f"joint {i}: q_min = {self.q_min[i]} is not below q_max = {self.q_max[i]}"
            )
        for key in ("v_max", "a_max", "j_max", "tau_max"):
            arr = getattr(self, key)
            if arr is not None and np.any(arr <= 0):
                i = int(np.flatnonzero(arr <= 0)[0])
                raise RobotModelError(f"joint {i}: {key} = {arr[i]}; expected a positive value")

    @property
    def n_dof(self) -> int:
        return int(self.q_min.shape[0])


# ----------------------------------------------------------------------------------------------
# URDF parsing helpers


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


def _link_supports(
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


def _parse_sara_limits(
    root: ET.Element, joint_names: tuple[str, ...], path: Path
) -> tuple[np.ndarray, np.ndarray]:
    """Acceleration and jerk limits ``(n_dof,)`` each from ``<sara_limits>``."""
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
    missing = [name for name in joint_names if name not in entries]
    if missing:
        raise RobotModelError(
            f"joint {missing[0]!r} has no acceleration/jerk limits in {path}"
            + (f" (nor {', '.join(repr(m) for m in missing[1:])})" if len(missing) > 1 else "")
            + f'; expected <sara_limits><joint name="{missing[0]}" acceleration="..." '
            'jerk="..."/></sara_limits> inside <robot>'
        )
    a = np.array([entries[name][0] for name in joint_names])
    j = np.array([entries[name][1] for name in joint_names])
    return a, j


# ----------------------------------------------------------------------------------------------
# Capsule fitting


def enclosing_radius(points: np.ndarray, rho: np.ndarray, ends: np.ndarray) -> float:
    """Smallest radius of the capsule on segment ``ends (2, 3)`` containing every
    ``ball(points[k], rho[k])``."""
    return float(np.max(point_segment_distance(points, ends) + rho))


def _volume(length: np.ndarray | float, radius: np.ndarray | float) -> np.ndarray | float:
    return np.pi * radius**2 * length + 4.0 / 3.0 * np.pi * radius**3


def _best_insets(
    t: np.ndarray, perp2: np.ndarray, rho: np.ndarray, lo: float, hi: float
) -> tuple[float, float, float]:
    """Grid search of the segment ``[a, b]`` on a fixed line: ``(volume, a, b)``.

    ``R(a, b) = max(G(a), H(b))`` with ``G(a) = max_k sqrt(perp_k^2 + max(a - t_k, 0)^2) + rho_k``
    and ``H`` the mirror image: points below ``a`` are the only ones ``a`` affects.
    """
    best = (np.inf, lo, hi)
    for _ in range(3):  # refine around the best cell
        a = np.linspace(lo, hi, _GRID)
        G = np.max(np.sqrt(perp2 + np.maximum(a[:, None] - t, 0.0) ** 2) + rho, axis=1)
        H = np.max(np.sqrt(perp2 + np.maximum(t - a[:, None], 0.0) ** 2) + rho, axis=1)
        R = np.maximum(G[:, None], H[None, :])
        length = a[None, :] - a[:, None]
        V = np.where(length >= 0, _volume(np.maximum(length, 0.0), R), np.inf)
        i, j = np.unravel_index(int(np.argmin(V)), V.shape)
        if V[i, j] < best[0]:
            best = (float(V[i, j]), float(a[i]), float(a[j]))
        step = (hi - lo) / (_GRID - 1)
        lo, hi = max(lo, min(a[i], a[j]) - step), min(hi, max(a[i], a[j]) + step)
        if hi - lo < 1e-7:
            break
    return best


def fit_capsule(
    points: np.ndarray, rho: np.ndarray | float = 0.0, axis_points: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """A small capsule ``(ends (2, 3), radius)`` containing every ``ball(points[k], rho[k])``.

    ``axis_points`` (default: ``points``) only steer the choice of the principal axes. The
    returned radius is the exact enclosing radius for the returned ends plus
    :data:`ENCLOSURE_SLACK_M`, so containment does not depend on the optimisation's quality.
    """
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    rho_arr = np.broadcast_to(np.asarray(rho, dtype=float), P.shape[:1]).copy()
    if P.shape[0] == 0 or not np.all(np.isfinite(P)) or np.any(rho_arr < 0):
        raise InputError(f"fit_capsule: {P.shape[0]} points / rho invalid; expected finite data")
    guide = P if axis_points is None else np.asarray(axis_points, dtype=float).reshape(-1, 3)
    centre = guide.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((guide - centre).T) if len(guide) > 1 else np.eye(3))
    best_vol, best_ends = np.inf, np.stack([centre, centre])
    d = P - centre
    for axis in vecs.T[::-1]:  # principal axis first
        t = d @ axis
        perp2 = np.maximum(np.einsum("ki,ki->k", d, d) - t * t, 0.0)
        vol, a, b = _best_insets(t, perp2, rho_arr, float(t.min()), float(t.max()))
        if vol < best_vol:
            best_vol, best_ends = vol, np.stack([centre + a * axis, centre + b * axis])

    def objective(x: np.ndarray) -> float:
        p0, seg = x[:3], x[3:] - x[:3]
        rel = P - p0
        ss = float(seg @ seg)
        s = np.clip(rel @ seg / ss, 0.0, 1.0) if ss > 1e-24 else np.zeros(len(P))
        gap = rel - s[:, None] * seg
        r = float(np.max(np.sqrt(np.einsum("ki,ki->k", gap, gap)) + rho_arr))
        return float(_volume(np.sqrt(ss), r))

    # Nelder-Mead polish over both end points, restarted once with a smaller simplex.
    x = best_ends.ravel()
    f = objective(x)
    size = max(float(np.ptp(P, axis=0).max()), 1e-3)
    for step in (0.05 * size, 0.01 * size):
        res = minimize(
            objective,
            x,
            method="Nelder-Mead",
            options={
                "initial_simplex": np.vstack([x, x + step * np.eye(6)]),
                "xatol": 1e-6,
                "fatol": 1e-11,
                "maxiter": 3000,
            },
        )
        if res.fun < f:
            x, f = res.x, float(res.fun)
    ends = x.reshape(2, 3)
    return ends, enclosing_radius(P, rho_arr, ends) + ENCLOSURE_SLACK_M


_FIT_CACHE: dict[tuple[str, int, int], tuple[tuple[str, ...], np.ndarray, np.ndarray]] = {}


def _fitted_capsules(
    path: Path, root: ET.Element
) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    stat = path.stat()
    key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    if key not in _FIT_CACHE:
        supports = _link_supports(root, path.parent)
        names = tuple(supports)
        ends = np.zeros((len(names), 2, 3))
        radii = np.zeros(len(names))
        for i, name in enumerate(names):
            ends[i], radii[i] = fit_capsule(*supports[name])
        _FIT_CACHE[key] = (names, ends, radii)
    names, ends, radii = _FIT_CACHE[key]
    return names, ends.copy(), radii.copy()


# ----------------------------------------------------------------------------------------------
# The model


def _as_pose(T: np.ndarray | None, what: str) -> np.ndarray:
    if T is None:
        return np.eye(4)
    M = np.array(T, dtype=float)
    if M.shape != (4, 4) or not np.all(np.isfinite(M)):
        raise InputError(f"{what} has shape {M.shape} or non-finite entries; expected (4, 4)")
    R = M[:3, :3]
    if (
        not np.allclose(M[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9)
        or not np.allclose(R.T @ R, np.eye(3), atol=1e-6)
        or np.linalg.det(R) < 0
    ):
        raise InputError(f"{what} is not a rigid transform (rotation + translation): {M.tolist()}")
    return M


class RobotModel:
    """A pinocchio model and fitted link capsules, built once from a URDF.

    Attributes (read-only by convention; arrays are not writeable):

    - ``name``, ``urdf_path``, ``n_dof``, ``joint_names`` (``(n_dof,)`` tuple in q order);
    - ``limits``: :class:`JointLimits` from ``<limit>`` and ``<sara_limits>``;
    - ``link_names``: the ``L`` links that carry a capsule (links with collision geometry,
      the base included), in URDF order;
    - ``capsules_local`` ``(L, 2, 3)``: capsule end points in each link's frame;
    - ``radius_m`` ``(L,)``: fitted radius plus ``margin_m``;
    - ``margin_m``; ``T_world_base`` ``(4, 4)``; ``pin_model`` / ``pin_data``.
    """

    def __init__(
        self,
        urdf_path: str | os.PathLike[str],
        *,
        name: str | None = None,
        T_world_base: np.ndarray | None = None,
        margin_m: float = 0.0,
    ) -> None:
        path = Path(urdf_path)
        if not path.is_file():
            raise RobotModelError(f"URDF file {str(path)!r} not found")
        if not (np.isfinite(margin_m) and margin_m >= 0):
            raise ParameterError(f"margin_m = {margin_m!r}; expected a finite value >= 0 (m)")
        try:
            root = ET.parse(path).getroot()
        except ET.ParseError as exc:
            raise RobotModelError(f"URDF file {str(path)!r} is not valid XML: {exc}") from exc
        if root.tag != "robot":
            raise RobotModelError(
                f"URDF file {str(path)!r} has root <{root.tag}>; expected <robot>"
            )
        try:
            model = pin.buildModelFromUrdf(str(path))
        except Exception as exc:  # pinocchio raises several exception types
            raise RobotModelError(f"pinocchio cannot build {str(path)!r}: {exc}") from exc

        joint_names = tuple(str(n) for n in model.names[1:])
        for jid in range(1, model.njoints):
            joint = model.joints[jid]
            if joint.nq != 1 or joint.nv != 1:
                raise RobotModelError(
                    f"joint {model.names[jid]!r} is {joint.shortname()} with nq={joint.nq}; "
                    "expected revolute or prismatic joints (continuous, planar and floating "
                    "joints are not supported)"
                )
        q_min = np.array(model.lowerPositionLimit, dtype=float)
        q_max = np.array(model.upperPositionLimit, dtype=float)
        v_max = np.array(model.velocityLimit, dtype=float)
        tau_max = np.array(model.effortLimit, dtype=float)
        for i, jn in enumerate(joint_names):
            if not (np.isfinite(q_min[i]) and np.isfinite(q_max[i]) and q_min[i] < q_max[i]):
                raise RobotModelError(
                    f"joint {jn!r} position limits [{q_min[i]}, {q_max[i]}]; expected finite "
                    "lower < upper in <limit>"
                )
            for label, arr in (("velocity", v_max), ("effort", tau_max)):
                if not (np.isfinite(arr[i]) and arr[i] > 0):
                    raise RobotModelError(
                        f"joint {jn!r} {label} limit = {arr[i]}; expected a positive value in "
                        "<limit>"
                    )
        a_max, j_max = _parse_sara_limits(root, joint_names, path)

        link_names, local, radius = _fitted_capsules(path, root)
        frame_ids = []
        for ln in link_names:
            if not model.existBodyName(ln):
                raise RobotModelError(f"link {ln!r} has no pinocchio body frame in {path}")
            frame_ids.append(model.getFrameId(ln, pin.FrameType.BODY))

        self.name: str = name or root.get("name") or path.stem
        self.urdf_path: Path = path
        self.pin_model: pin.Model = model
        self.pin_data: pin.Data = model.createData()
        self.n_dof: int = int(model.nv)
        self.joint_names: tuple[str, ...] = joint_names
        self.limits = JointLimits(q_min, q_max, v_max, a_max, j_max, tau_max)
        self.link_names: tuple[str, ...] = link_names
        self.margin_m: float = float(margin_m)
        local.flags.writeable = False
        radius = radius + self.margin_m
        radius.flags.writeable = False
        self.capsules_local: np.ndarray = local
        self.radius_m: np.ndarray = radius
        self._T_world_base = _as_pose(T_world_base, "T_world_base")
        self._T_world_base.flags.writeable = False
        self._base_is_identity = bool(np.array_equal(self._T_world_base, np.eye(4)))
        self._frame_ids: tuple[int, ...] = tuple(int(f) for f in frame_ids)
        self._oMf = self.pin_data.oMf  # reference into pin_data, valid as long as it lives
        # local end points as homogeneous columns (L, 4, 2)
        self._local_h = np.concatenate([local, np.ones((len(link_names), 2, 1))], axis=2).transpose(
            0, 2, 1
        )

    # -- basic accessors ------------------------------------------------------------------------

    @property
    def T_world_base(self) -> np.ndarray:
        """Base pose in the world ``(4, 4)``, fixed at construction."""
        return self._T_world_base

    @property
    def n_links(self) -> int:
        return len(self.link_names)

    @property
    def frame_names(self) -> tuple[str, ...]:
        """All pinocchio frame names (links, joints, fixed frames) usable in :meth:`frame_pose`."""
        return tuple(f.name for f in self.pin_model.frames)

    def __repr__(self) -> str:
        return (
            f"RobotModel(name={self.name!r}, n_dof={self.n_dof}, links={len(self.link_names)}, "
            f"margin_m={self.margin_m})"
        )

    def _check_q(self, q: np.ndarray, what: str = "q") -> np.ndarray:
        arr = np.asarray(q, dtype=float)
        # The sum is NaN/inf iff an entry is (or the entries are absurdly large): one cheap test.
        if arr.shape != (self.n_dof,) or not np.isfinite(arr.sum()):
            raise InputError(
                f"{what} has shape {arr.shape} or non-finite entries; expected ({self.n_dof},) "
                f"finite values for {self.name}"
            )
        return arr

    # -- kinematics -----------------------------------------------------------------------------

    def _link_frames(self, q: np.ndarray) -> np.ndarray:
        """Forward kinematics: base-frame placements of the capsule links ``(L, 4, 4)``."""
        pin.forwardKinematics(self.pin_model, self.pin_data, q)
        pin.updateFramePlacements(self.pin_model, self.pin_data)
        oMf = self._oMf
        return np.array([oMf[f].homogeneous for f in self._frame_ids])

    def _to_world(self, H: np.ndarray) -> np.ndarray:
        return H if self._base_is_identity else np.matmul(self._T_world_base, H)

    def link_poses(self, q: np.ndarray) -> np.ndarray:
        """World poses of the capsule-carrying links ``(L, 4, 4)`` at configuration ``q``."""
        return self._to_world(self._link_frames(self._check_q(q)))

    def frame_pose(self, q: np.ndarray, frame: str) -> np.ndarray:
        """World pose ``(4, 4)`` of any pinocchio frame (link, joint or fixed frame) by name."""
        q = self._check_q(q)
        if not self.pin_model.existFrame(frame):
            raise UnknownNameError("frame", frame, self.frame_names)
        fid = self.pin_model.getFrameId(frame)
        pin.framesForwardKinematics(self.pin_model, self.pin_data, q)
        return self._T_world_base @ self.pin_data.oMf[fid].homogeneous

    def link_capsules(
        self, q: np.ndarray, out_ends: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """World-frame capsules at ``q``: ``(ends (L, 2, 3), radius_m (L,))``.

        ``out_ends`` (``(L, 2, 3)`` float) is filled and returned when given. The radii array is
        the model's own (read-only) ``radius_m``.
        """
        H = self._to_world(self._link_frames(self._check_q(q)))
        ends = np.matmul(H[:, :3, :], self._local_h).transpose(0, 2, 1)  # (L, 2, 3)
        if out_ends is None:
            return np.ascontiguousarray(ends), self.radius_m
        if out_ends.shape != ends.shape:
            raise InputError(f"out_ends has shape {out_ends.shape}; expected {ends.shape}")
        out_ends[...] = ends
        return out_ends, self.radius_m

    def link_capsules_batch(self, qs: np.ndarray) -> np.ndarray:
        """World-frame capsule ends for many configurations: ``(S, n_dof) -> (S, L, 2, 3)``."""
        Q = np.asarray(qs, dtype=float)
        if Q.ndim != 2 or Q.shape[1] != self.n_dof or not np.all(np.isfinite(Q)):
            raise InputError(
                f"qs has shape {Q.shape} or non-finite entries; expected (S, {self.n_dof})"
            )
        H = np.zeros((Q.shape[0], self.n_links, 4, 4))
        for s in range(Q.shape[0]):
            H[s] = self._link_frames(Q[s])
        H = self._to_world(H)
        return np.matmul(H[:, :, :3, :], self._local_h).transpose(0, 1, 3, 2).copy()

    def link_jacobians(self, q: np.ndarray) -> np.ndarray:
        """Jacobians of the capsule-carrying links ``(L, 6, n_dof)``.

        Rows 0-2: linear velocity of the link frame's origin, rows 3-5: angular velocity, both
        in world axes (pinocchio's LOCAL_WORLD_ALIGNED rotated by ``T_world_base``).
        """
        q = self._check_q(q)
        m, d = self.pin_model, self.pin_data
        pin.computeJointJacobians(m, d, q)
        pin.updateFramePlacements(m, d)
        Rb = self._T_world_base[:3, :3]
        J = np.zeros((self.n_links, 6, self.n_dof))
        for i, fid in enumerate(self._frame_ids):
            Jf = pin.getFrameJacobian(m, d, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            J[i, :3] = Rb @ Jf[:3]
            J[i, 3:] = Rb @ Jf[3:]
        return J

    def capsule_end_jacobians(self, q: np.ndarray) -> np.ndarray:
        """Jacobians of the world-frame capsule end points ``(L, 2, 3, n_dof)``:
        ``d ends[l, e] / dt = J[l, e] @ dq``."""
        J = self.link_jacobians(q)
        H = self.link_poses(q)
        ends = np.matmul(H[:, :3, :], self._local_h).transpose(0, 2, 1)  # (L, 2, 3)
        lever = ends - H[:, None, :3, 3]  # from each link's origin, world axes
        Jv, Jw = J[:, None, :3, :], J[:, None, 3:, :]
        # v_end = v_origin + w x lever = v_origin - lever x w
        return Jv - np.cross(lever[..., :, None], Jw, axisa=-2, axisb=-2, axisc=-2)

    def capsule_end_velocities(self, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
        """World-frame velocities of the capsule end points ``(L, 2, 3)`` at ``(q, dq)``."""
        dq = self._check_q(dq, "dq")
        return np.einsum("lein,n->lei", self.capsule_end_jacobians(q), dq)

    # -- dynamics -------------------------------------------------------------------------------

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """Joint-space inertia matrix ``(n_dof, n_dof)`` from ``pin.crba``, symmetrised."""
        M = np.array(pin.crba(self.pin_model, self.pin_data, self._check_q(q)))
        upper = np.triu(M)
        return upper + np.triu(M, 1).T


# ----------------------------------------------------------------------------------------------
# Loading by name


def urdf_dir() -> Path:
    """The folder with ``<name>.urdf``: ``$SARA_URDF_DIR``, else ``<repository>/urdf``."""
    env = os.environ.get("SARA_URDF_DIR")
    if env:
        return Path(env)
    return Path(__file__).resolve().parent.parent.parent / "urdf"


def robot_names() -> tuple[str, ...]:
    """Valid robot names: the shipped ones plus every ``*.urdf`` in :func:`urdf_dir`."""
    folder = urdf_dir()
    found = {p.stem for p in folder.glob("*.urdf")} if folder.is_dir() else set()
    return tuple(sorted(found | set(ROBOT_NAMES)))


def load_robot(
    name_or_path: str | os.PathLike[str],
    *,
    T_world_base: np.ndarray | None = None,
    margin_m: float = 0.0,
) -> RobotModel:
    """Load a robot by name (``'panda'``, ``'ur5e'``, or any ``<name>.urdf`` in
    :func:`urdf_dir`) or by URDF path. Capsule fits are cached per file.

    Raises :class:`UnknownNameError` for an unknown name (listing the valid choices) and
    :class:`RobotModelError` for a missing or invalid URDF.
    """
    text = os.fspath(name_or_path)
    names = robot_names()
    if text in names:
        path = urdf_dir() / f"{text}.urdf"
        if not path.is_file():
            raise RobotModelError(
                f"robot {text!r}: URDF {str(path)!r} not found; expected it in the folder set by "
                "SARA_URDF_DIR or the repository's urdf/ folder"
            )
        return RobotModel(path, name=text, T_world_base=T_world_base, margin_m=margin_m)
    looks_like_path = text.endswith(".urdf") or os.sep in text or "/" in text
    if looks_like_path or Path(text).is_file():
        return RobotModel(text, T_world_base=T_world_base, margin_m=margin_m)
    raise UnknownNameError("robot", text, names)
