"""Kinematics of robot points for JSSA (Liu et al. 2022 eq. 8-11): position, velocity, acceleration
and the jerk map ``p''' = J u + c`` of points fixed in a link frame.

For a point ``p`` fixed in link ``l`` (world frame), with ``J_p (3, n)`` its Jacobian:

- ``p'   = J_p q'``
- ``p''  = J_p q'' + J_p' q'``
- ``p''' = J_p u + c``,  ``c = J_p'' q' + 2 J_p' q''``  (Liu et al. 2022 eq. 10-11, ``u = q'''``)

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
from sara_app.safety.jssa_kernels import point_terms

DRIFT_STEP_S = 1e-4
"""Time step ``h`` of the central difference for the drift jerk ``c``."""


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
        self._identity_base = bool(np.array_equal(self._R_wb, np.eye(3)))
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

    def points(
        self, link_idx: np.ndarray, p_world: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Velocity ``(K, 3)``, acceleration ``(K, 3)``, drift jerk ``c (K, 3)`` and Jacobian
        ``J_p (K, 3, n)`` (all world frame) of points ``p_world (K, 3)`` fixed in links
        ``link_idx (K,)``, at the state of the last :meth:`update` (compiled:
        :func:`sara_app.safety.jssa_kernels.point_terms`)."""
        K = len(link_idx)
        p_b = (np.asarray(p_world, dtype=float) - self._t_wb) @ self._R_wb  # R^T (p - t)
        v, a, c = np.empty((K, 3)), np.empty((K, 3)), np.empty((K, 3))
        Jp = np.empty((K, 3, self.n))
        li = np.asarray(link_idx, dtype=np.int64)
        point_terms(self._V, self._A, self._J, self.support_mask, li, p_b, self.h, v, a, c, Jp)
        if self._identity_base:
            return v, a, c, Jp
        R = self._R_wb
        return v @ R.T, a @ R.T, c @ R.T, np.matmul(R, Jp)
