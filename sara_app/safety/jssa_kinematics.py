"""Kinematics of robot points for JSSA (seed 002 eq. 8-11): position, velocity, acceleration
and the jerk map ``p''' = J u + c`` of points fixed in a link frame.

For a point ``p`` fixed in link ``l`` (world frame), with ``J_p (3, n)`` its Jacobian:

- ``p'   = J_p q'``
- ``p''  = J_p q'' + J_p' q'``
- ``p''' = J_p u + c``,  ``c = J_p'' q' + 2 J_p' q''``  (seed 002 eq. 10-11, ``u = q'''``)

``J_p`` and ``J_p'`` come from pinocchio's world-frame joint Jacobians ``data.J`` and their time
variation ``data.dJ`` (``computeJointJacobiansTimeVariation``): with ``J = [J_lin; J_ang]``
(spatial velocity at the pinocchio origin), ``J_p = M_l (J_lin - [p]x J_ang)`` and
``J_p' = M_l (J_lin' - [p]x J_ang' - [p']x J_ang)``, ``M_l`` masking the joints that do not
support link ``l``. Pinocchio has no ``J''``: the drift ``c`` is the time derivative of the
acceleration ``A(q, q', q'') = J_p q'' + J_p' q'`` along the jerk-free motion (``u = 0``), taken
as a central difference with step ``h`` over two more pinocchio evaluations (error O(h^2)); the
point's positions at ``t +- h`` are its Taylor expansion to second order (error O(h^3), which adds
O(h^2) to ``c``). The tests compare all four quantities with finite differences of simulated
motion.

Not thread-safe: one object owns one pinocchio ``Data`` and its buffers.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from sara_app.robot.model import RobotModel

DRIFT_STEP_S = 1e-4
"""Time step ``h`` of the central difference for the drift jerk ``c``."""


def _cross(p: np.ndarray, A: np.ndarray) -> np.ndarray:
    """``p x A`` column by column: ``p (K, 3)``, ``A (K or 1, 3, n)`` -> ``(K, 3, n)``
    (np.cross costs ~25 us of axis handling per call at these sizes)."""
    px, py, pz = p[:, 0, None], p[:, 1, None], p[:, 2, None]
    ax, ay, az = A[:, 0, :], A[:, 1, :], A[:, 2, :]
    return np.stack([py * az - pz * ay, pz * ax - px * az, px * ay - py * ax], axis=1)


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise ``a x b`` of ``(..., 3)`` arrays (no np.cross axis handling)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    out[..., 0] = a1 * b2 - a2 * b1
    out[..., 1] = a2 * b0 - a0 * b2
    out[..., 2] = a0 * b1 - a1 * b0
    return out


class PointKinematics:
    """Batched kinematics of points fixed in the robot's capsule links.

    Call :meth:`update` once per state, then :meth:`points` for any number of points.
    Arrays: ``link_idx (K,)`` int into ``robot.link_names``; positions ``(K, 3)`` world frame.

    :meth:`update` keeps, per state (``t``, ``t + h``, ``t - h``) and link, the spatial velocity
    ``V = J_l q'`` and the spatial acceleration ``A = J_l q'' + J_l' q'`` (``J_l`` the masked
    world Jacobian, rows linear at the origin then angular). A point ``p`` of link ``l`` then has
    ``p' = V_lin + w x p`` and ``p'' = A_lin + A_ang x p + w x p'`` (``w = V_ang``), which is
    ``J_p q'' + J_p' q'`` with the ``J_p`` and ``J_p'`` of the module notes, in a few vector
    operations per point instead of ``(3, n)`` matrix products.
    """

    def __init__(self, robot: RobotModel) -> None:
        self.robot = robot
        self.n = robot.n_dof
        model = robot.pin_model
        self._model = model
        self._data = model.createData()
        L = robot.n_links
        mask = np.zeros((L, self.n))
        for i, name in enumerate(robot.link_names):
            fid = model.getFrameId(name, pin.FrameType.BODY)
            for jid in model.supports[model.frames[fid].parentJoint]:
                if jid > 0:
                    mask[i, model.idx_vs[jid]] = 1.0
        self.support_mask = mask  # (L, n) 1 where joint j moves link l
        self.movable = mask.any(axis=1)  # (L,) links that some joint moves
        T = robot.T_world_base
        self._R_wb = np.ascontiguousarray(T[:3, :3])
        self._t_wb = T[:3, 3].copy()
        self._J = np.zeros((6, self.n))  # J at t (base frame)
        self._V = np.zeros((3, L, 6))  # spatial velocity per state and link
        self._A = np.zeros((3, L, 6))  # spatial acceleration per state and link
        self.h = DRIFT_STEP_S

    def update(self, q: np.ndarray, q_dot: np.ndarray, q_ddot: np.ndarray) -> None:
        """Evaluate the Jacobians at ``(q, q', q'')`` and at ``t +- h`` along ``u = 0``.

        Inputs ``(n,)`` finite (the caller checks).
        """
        h = self.h
        m, d = self._model, self._data
        mask = self.support_mask
        for k, sgn in enumerate((0.0, 1.0, -1.0)):
            qk = q + sgn * h * q_dot + 0.5 * h * h * q_ddot if sgn else q
            vk = q_dot + sgn * h * q_ddot if sgn else q_dot
            dJ = pin.computeJointJacobiansTimeVariation(m, d, qk, vk)
            J = d.J
            if k == 0:
                self._J[:] = J
            # (L, 6): per link, only the joints that support it
            self._V[k] = (mask * vk) @ J.T
            self._A[k] = (mask * q_ddot) @ J.T + (mask * vk) @ dJ.T

    def angular_velocity(self, link_idx: np.ndarray) -> np.ndarray:
        """World-frame angular velocities ``(K, 3)`` of links ``link_idx (K,)`` at ``t``."""
        return self._V[0, link_idx, 3:] @ self._R_wb.T

    def _acc(self, k: int, li: np.ndarray, p_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Velocity and acceleration ``(K, 3)`` (base frame) of points ``p_b`` at state ``k``."""
        V, A = self._V[k, li], self._A[k, li]
        w = V[:, 3:]
        v = V[:, :3] + cross3(w, p_b)
        a = A[:, :3] + cross3(A[:, 3:], p_b) + cross3(w, v)
        return v, a

    def points(
        self, link_idx: np.ndarray, p_world: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Velocity ``(K, 3)``, acceleration ``(K, 3)``, drift jerk ``c (K, 3)`` and Jacobian
        ``J_p (K, 3, n)`` (all world frame) of points ``p_world (K, 3)`` fixed in links
        ``link_idx (K,)``, at the state of the last :meth:`update`."""
        mask = self.support_mask[link_idx]
        p_b = (p_world - self._t_wb) @ self._R_wb  # R^T (p - t), row vectors
        v, a = self._acc(0, link_idx, p_b)
        h = self.h
        p_k = p_b + 0.5 * h * h * a
        a_plus = self._acc(1, link_idx, p_k + h * v)[1]
        a_minus = self._acc(2, link_idx, p_k - h * v)[1]
        c = (a_plus - a_minus) / (2.0 * h)
        J = self._J
        Jp = J[None, :3, :] - _cross(p_b, J[None, 3:, :])
        Jp *= mask[:, None, :]
        R = self._R_wb
        return v @ R.T, a @ R.T, c @ R.T, np.matmul(R, Jp)
