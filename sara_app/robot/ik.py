"""Inverse kinematics for editing task waypoints: damped least squares on one frame's pose.

:func:`solve_ik` moves a frame of a :class:`~sara_app.robot.model.RobotModel` (by default the
tool frame, :func:`end_effector_frame`) to a world pose ``T_world_target (4, 4)``:

- error ``e = [p_target - p(q); w log3(R_target R(q)^T)]`` (world axes; ``w`` [m/rad] weighs
  rotation against position), Jacobian from pinocchio's frame Jacobian (LOCAL_WORLD_ALIGNED,
  rotated by the robot's base pose);
- step ``dq = J^T (J J^T + lambda^2 I)^-1 e`` with the columns of joints resting on a limit and
  pushed outward removed, at most ``max_step_rad`` per joint, ``q`` clamped to the limits;
- warm-started from ``q0`` (the old waypoint); when that does not converge, ``restarts`` seeded
  random starts (alternately near ``q0`` and anywhere inside the limits) and the converged
  solution closest to ``q0`` is returned.

The result always lies inside the joint limits; ``converged`` is False (and the residuals say
by how much) when the target is out of reach. Nothing here raises for an unreachable target;
callers refuse it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from sara_app.errors import InputError, UnknownNameError
from sara_app.robot.model import RobotModel

TOOL_FRAMES: tuple[str, ...] = ("panda_hand_tcp", "tool0")
"""Tool frames preferred as the end effector when the robot has one of them."""


@dataclass(frozen=True)
class IkResult:
    """``q (n_dof,)`` inside the joint limits; residual position error [m] and rotation error
    [rad] of the frame at ``q``; ``converged``: both within tolerance (rotation ignored when
    solving for position only); ``iterations`` over all starts; ``starts`` tried."""

    q: np.ndarray
    position_error_m: float
    rotation_error_rad: float
    converged: bool
    iterations: int
    starts: int


def end_effector_frame(robot: RobotModel) -> str:
    """The tool frame of ``robot``: the first of :data:`TOOL_FRAMES` it has, else its last
    capsule link."""
    for name in TOOL_FRAMES:
        if robot.pin_model.existFrame(name):
            return name
    return robot.link_names[-1]


def _frame_id(robot: RobotModel, frame: str) -> int:
    if not robot.pin_model.existFrame(frame):
        raise UnknownNameError("frame", frame, robot.frame_names)
    return int(robot.pin_model.getFrameId(frame))


def frame_jacobian(robot: RobotModel, q: np.ndarray, frame: str) -> tuple[np.ndarray, np.ndarray]:
    """World pose ``T_world_frame (4, 4)`` and Jacobian ``J (6, n_dof)`` of ``frame`` at ``q``.

    Rows 0-2: velocity of the frame's origin, rows 3-5: angular velocity, world axes.
    """
    return _pose_and_jacobian(robot, np.asarray(q, dtype=float), _frame_id(robot, frame))


def _pose_and_jacobian(robot: RobotModel, q: np.ndarray, fid: int) -> tuple[np.ndarray, np.ndarray]:
    m, d = robot.pin_model, robot.pin_data
    pin.computeJointJacobians(m, d, q)
    pin.updateFramePlacement(m, d, fid)
    Jf = pin.getFrameJacobian(m, d, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    T_base = robot.T_world_base
    T = T_base @ d.oMf[fid].homogeneous
    J = np.empty((6, robot.n_dof))
    J[:3] = T_base[:3, :3] @ Jf[:3]
    J[3:] = T_base[:3, :3] @ Jf[3:]
    return T, J


def pose_error(T_world_target: np.ndarray, T_world_frame: np.ndarray) -> np.ndarray:
    """``(6,)``: position error [m] and rotation vector [rad] taking the frame onto the target,
    both in world axes."""
    e = np.empty(6)
    e[:3] = T_world_target[:3, 3] - T_world_frame[:3, 3]
    e[3:] = pin.log3(T_world_target[:3, :3] @ T_world_frame[:3, :3].T)
    return e


def _checked_target(T: np.ndarray) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(
            f"T_world_target has shape {T.shape} or non-finite entries; expected (4, 4)"
        )
    R = T[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise InputError("T_world_target's rotation block is not a rotation matrix")
    return T


@dataclass(frozen=True)
class _Settings:
    orientation: bool
    rotation_weight_m: float
    tol_position_m: float
    tol_rotation_rad: float
    max_iterations: int
    damping: float
    max_step_rad: float


class _Solver:
    def __init__(self, robot: RobotModel, fid: int, T: np.ndarray, s: _Settings) -> None:
        self.robot, self.fid, self.T, self.s = robot, fid, T, s
        self.q_min, self.q_max = robot.limits.q_min, robot.limits.q_max
        self.rows = slice(0, 6 if s.orientation else 3)
        self.w = np.array([1.0, 1.0, 1.0] + [s.rotation_weight_m] * 3)[self.rows]
        self.iterations = 0

    def errors(self, q: np.ndarray) -> tuple[float, float]:
        T, _ = _pose_and_jacobian(self.robot, q, self.fid)
        e = pose_error(self.T, T)
        return float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))

    def done(self, ep: float, er: float) -> bool:
        return ep <= self.s.tol_position_m and (
            not self.s.orientation or er <= self.s.tol_rotation_rad
        )

    def step(self, q: np.ndarray, e: np.ndarray, J: np.ndarray) -> np.ndarray:
        """One damped least-squares step with outward-pushed joints at their limits frozen."""
        lam2 = self.s.damping**2
        free = np.ones(q.shape[0], dtype=bool)
        dq = np.zeros_like(q)
        for _ in range(3):
            Jf = J * free
            dq = Jf.T @ np.linalg.solve(Jf @ Jf.T + lam2 * np.eye(J.shape[0]), e)
            blocked = ((q <= self.q_min) & (dq < 0)) | ((q >= self.q_max) & (dq > 0))
            if not np.any(blocked & free):
                break
            free &= ~blocked
        big = np.abs(dq).max()
        if big > self.s.max_step_rad:
            dq *= self.s.max_step_rad / big
        return np.clip(q + dq, self.q_min, self.q_max)

    def descend(self, q: np.ndarray) -> tuple[np.ndarray, float, float]:
        """Iterate from ``q``; the last iterate and its position / rotation errors."""
        best = np.inf
        stall = 0
        for _ in range(self.s.max_iterations):
            T, J = _pose_and_jacobian(self.robot, q, self.fid)
            e6 = pose_error(self.T, T)
            ep, er = float(np.linalg.norm(e6[:3])), float(np.linalg.norm(e6[3:]))
            if self.done(ep, er):
                return q, ep, er
            cost = float(np.linalg.norm(e6[self.rows] * self.w))
            stall = stall + 1 if cost > 0.999 * best else 0
            best = min(best, cost)
            if stall >= 15:
                break
            self.iterations += 1
            q = self.step(q, e6[self.rows] * self.w, J[self.rows] * self.w[:, None])
        ep, er = self.errors(q)
        return q, ep, er


def solve_ik(
    robot: RobotModel,
    T_world_target: np.ndarray,
    q0: np.ndarray,
    *,
    frame: str | None = None,
    orientation: bool = True,
    rotation_weight_m: float = 0.3,
    tol_position_m: float = 1e-4,
    tol_rotation_rad: float = 1e-3,
    max_iterations: int = 200,
    restarts: int = 16,
    seed: int = 0,
    damping: float = 1e-3,
    max_step_rad: float = 0.2,
) -> IkResult:
    """Joint positions that put ``frame`` (default :func:`end_effector_frame`) at
    ``T_world_target (4, 4)`` (world frame; with ``orientation`` False only its position
    counts), starting from ``q0 (n_dof,)`` (clamped into the limits first).

    Raises :class:`InputError` for a malformed target or ``q0`` and
    :class:`UnknownNameError` for an unknown frame; an unreachable target gives
    ``converged=False`` with the best residuals found.
    """
    T = _checked_target(T_world_target)
    q_start = np.asarray(q0, dtype=float)
    if q_start.shape != (robot.n_dof,) or not np.all(np.isfinite(q_start)):
        raise InputError(
            f"q0 has shape {q_start.shape} or non-finite entries; expected ({robot.n_dof},)"
        )
    fid = _frame_id(robot, frame or end_effector_frame(robot))
    settings = _Settings(
        orientation,
        rotation_weight_m,
        tol_position_m,
        tol_rotation_rad,
        max_iterations,
        damping,
        max_step_rad,
    )
    solver = _Solver(robot, fid, T, settings)
    lim = robot.limits
    q_start = np.clip(q_start, lim.q_min, lim.q_max)
    q, ep, er = solver.descend(q_start.copy())
    starts = 1
    if solver.done(ep, er):
        return IkResult(q, ep, er, True, solver.iterations, starts)
    best = (q, ep, er)
    rot_w = rotation_weight_m if orientation else 0.0
    solutions = []
    rng = np.random.default_rng(seed)
    for i in range(restarts):
        starts += 1
        if i % 2 == 0:  # near the warm start (solutions close to the old waypoint first)
            q_try = np.clip(
                q_start + rng.normal(scale=0.5, size=q_start.shape), lim.q_min, lim.q_max
            )
        else:
            q_try = rng.uniform(lim.q_min, lim.q_max)
        q, ep, er = solver.descend(q_try)
        if solver.done(ep, er):
            solutions.append(q)
        elif np.hypot(ep, rot_w * er) < np.hypot(best[1], rot_w * best[2]):
            best = (q, ep, er)
    if solutions:
        q = min(solutions, key=lambda s: float(np.linalg.norm(s - q_start)))
        ep, er = solver.errors(q)
        return IkResult(q, ep, er, True, solver.iterations, starts)
    return IkResult(best[0], best[1], best[2], False, solver.iterations, starts)


def pose_from_wxyz(wxyz: np.ndarray, position_m: np.ndarray) -> np.ndarray:
    """``(4, 4)`` pose from a unit quaternion ``(w, x, y, z)`` (normalised here) and a
    position ``(3,)``."""
    qw = np.asarray(wxyz, dtype=float)
    p = np.asarray(position_m, dtype=float)
    n = float(np.linalg.norm(qw))
    if qw.shape != (4,) or p.shape != (3,) or not (np.isfinite(n) and n > 1e-9):
        raise InputError(f"pose wxyz {qw.shape} / position {p.shape}; expected (4,) / (3,)")
    if not np.all(np.isfinite(p)):
        raise InputError(f"position {p.tolist()} is not finite")
    w, x, y, z = qw / n
    T = np.eye(4)
    T[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    T[:3, 3] = p
    return T
