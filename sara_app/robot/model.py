"""Robot model: pinocchio kinematics and dynamics plus link capsules fitted once from the URDF.

A :class:`RobotModel` is built from a URDF whose joints are revolute or prismatic with position,
velocity and effort limits in ``<limit>`` and acceleration and jerk limits in a ``<sara_limits>``
element (:mod:`sara_app.robot.urdf`). Every URDF link with collision geometry (the base
included) carries one capsule enclosing its true collision primitives
(:mod:`sara_app.robot.capsule_fit`), fitted once per URDF file; per configuration only the end
points are transformed.

Frames and conventions: capsule ends ``(L, 2, 3)`` and radii ``(L,)`` as in
:mod:`sara_app.geometry.shapes`; world frame = ``T_world_base @`` pinocchio's frame placements (the
pinocchio "universe" is the URDF root link's frame). Angles in rad, lengths in m.

Not thread-safe: a model owns one ``pinocchio.Data``; use one model per thread.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pinocchio as pin

from sara_app.errors import InputError, ParameterError, RobotModelError, UnknownNameError
from sara_app.robot.capsule_fit import fitted_capsules
from sara_app.robot.urdf import check_links, parse_sara_limits

ROBOT_NAMES: tuple[str, ...] = ("panda", "ur10e", "ur5e")
"""Robots shipped in the repository's ``urdf/`` folder (``<name>.urdf``)."""


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
        joint_limits: Mapping[str, tuple[float, float]] | None = None,
    ) -> None:
        """``joint_limits``: joint name -> (acceleration, jerk) for what the URDF's
        ``<sara_limits>`` lacks (or overriding it)."""
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
        a_max, j_max = parse_sara_limits(root, joint_names, path, joint_limits)
        check_links(root, path)

        link_names, local, radius = fitted_capsules(path, root)
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


def urdf_path(name_or_path: str | os.PathLike[str]) -> Path:
    """The URDF file of a robot name (``'panda'``, ``'ur5e'``, ``'ur10e'``, or any
    ``<name>.urdf`` in :func:`urdf_dir`) or path. Raises :class:`UnknownNameError` for an
    unknown name (listing the valid choices) and :class:`RobotModelError` for a missing file."""
    text = os.fspath(name_or_path)
    names = robot_names()
    if text in names:
        path = urdf_dir() / f"{text}.urdf"
        if not path.is_file():
            raise RobotModelError(
                f"robot {text!r}: URDF {str(path)!r} not found; expected it in the folder set by "
                "SARA_URDF_DIR or the repository's urdf/ folder"
            )
        return path
    looks_like_path = text.endswith(".urdf") or os.sep in text or "/" in text
    if looks_like_path or Path(text).is_file():
        if not Path(text).is_file():
            raise RobotModelError(f"URDF file {text!r} not found")
        return Path(text)
    raise UnknownNameError("robot", text, names)


def load_robot(
    name_or_path: str | os.PathLike[str],
    *,
    T_world_base: np.ndarray | None = None,
    margin_m: float = 0.0,
    joint_limits: Mapping[str, tuple[float, float]] | None = None,
) -> RobotModel:
    """Load a robot by name or URDF path (:func:`urdf_path`); ``joint_limits`` as for
    :class:`RobotModel`. Capsule fits are cached per file."""
    path = urdf_path(name_or_path)
    text = os.fspath(name_or_path)
    name = text if text in robot_names() else None
    return RobotModel(
        path, name=name, T_world_base=T_world_base, margin_m=margin_m, joint_limits=joint_limits
    )
