"""Link kinetic energies (seed 003 Sec. VII, eq. 44-48) and link twists at trajectory samples.

For a link carried by joint ``m`` (pinocchio's parent joint of the link frame), the energy a
contact with it can transfer is (eq. 46)::

    T_i(q, q_dot) = 1/2 q_dot^T E_i B(q) E_i q_dot,

``B`` the joint-space inertia matrix (``pin.crba``) and ``E_i`` the diagonal 0/1 matrix that keeps
the joints supporting joint ``m`` (for a serial chain the joints ``1..m``). The base link has
``T = 0``; the last link's ``T`` is the robot's whole kinetic energy ``1/2 q_dot^T B q_dot``.
Eq. 47-48 take the larger energy at the two ends of each interval: :func:`interval_energy_J`.

Between-sample shortcut (named, as DESIGN.md asks): like seed 003, the energy over an interval is
taken as the larger of its end values; the energy can peak between samples (by a second-order
amount for short intervals). Keep intervals short or add a margin to the thresholds.

:class:`LinkMotion` also returns, at the same samples, the world-frame velocity of each link
capsule's first end ``p1`` and the link's angular velocity ``omega`` (the inputs of seed 003
Thm VI.1, eq. 25). Units: J, m/s, rad/s; frames: world (``model.T_world_base`` applied).

Bad input never raises on the hot path: a sample with a non-finite ``q`` or ``q_dot`` gets
``T = inf`` and NaN velocities, which every predicate downstream treats as unsafe.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from sara_app.errors import InputError
from sara_app.robot.model import RobotModel
from sara_app.robot.occupancy import RobotOccupancy


@dataclass(frozen=True)
class LinkSamples:
    """Link quantities at ``S`` samples (views into the owner's buffers; copy to keep).

    ``energy_J (S, L)``; ``ends (S, L, 2, 3)`` world capsule ends (m); ``p1_dot (S, L, 3)``
    velocity of ``ends[..., 0, :]`` (m/s); ``omega (S, L, 3)`` link angular velocity (rad/s).
    """

    energy_J: np.ndarray
    ends: np.ndarray
    p1_dot: np.ndarray
    omega: np.ndarray


def support_mask(model: RobotModel) -> np.ndarray:
    """``(L, n)`` bool: joint ``j`` supports (moves) link ``i``; the diagonal of ``E_i``."""
    pm = model.pin_model
    mask = np.zeros((model.n_links, model.n_dof), dtype=bool)
    for i, fid in enumerate(model._frame_ids):
        m = int(pm.frames[fid].parentJoint)
        for jid in pm.supports[m].tolist()[1:]:
            mask[i, pm.idx_vs[jid]] = True
    return mask


def interval_energy_J(energy_J: np.ndarray) -> np.ndarray:
    """Eq. 47-48: ``(K+1, L)`` sample energies -> ``(K, L)`` max of both interval ends."""
    return np.maximum(energy_J[:-1], energy_J[1:])


class LinkMotion:
    """Energies and twists of every capsule link at trajectory samples, for one robot.

    Built once per model (own ``pinocchio.Data``, masks, buffers grown on demand). Not
    thread-safe. Typical use per control cycle with a shielded trajectory ``traj``::

        samples = motion.evaluate(traj.q, traj.v)          # (K+1, ...) arrays
        T_interval = interval_energy_J(samples.energy_J)   # (K, L)
    """

    def __init__(self, model: RobotModel, occupancy: RobotOccupancy | None = None) -> None:
        self.model = model
        self.n_dof, self.n_links = model.n_dof, model.n_links
        self._data = model.pin_model.createData()
        self.mask = support_mask(model)
        self.mask.flags.writeable = False
        self._maskf = self.mask.astype(float)
        self._occ = occupancy or RobotOccupancy(model)
        T0 = np.asarray(model.T_world_base, dtype=float)
        self._R_wb, self._t_wb = T0[:3, :3].copy(), T0[:3, 3].copy()
        self._identity = bool(np.array_equal(T0, np.eye(4)))
        self._iu = np.triu_indices(self.n_dof, 1)
        self._cap = 0
        self._grow(16)

    def _grow(self, S: int) -> None:
        if S <= self._cap:
            return
        n, L = self.n_dof, self.n_links
        self._cap = S
        self._M = np.zeros((S, n, n))
        self._J = np.zeros((S, 6, n))
        self._T = np.zeros((S, L))
        self._pd = np.zeros((S, L, 3))
        self._w = np.zeros((S, L, 3))

    def _inputs(
        self, q: np.ndarray, q_dot: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        Q = np.asarray(q, dtype=float)
        V = np.asarray(q_dot, dtype=float)
        if Q.ndim != 2 or Q.shape[1] != self.n_dof or V.shape != Q.shape:
            raise InputError(
                f"q {Q.shape} and q_dot {V.shape}: expected equal shapes (S, {self.n_dof})"
            )
        bad = ~(np.isfinite(Q).all(axis=1) & np.isfinite(V).all(axis=1))
        if bad.any():
            Q, V = np.where(bad[:, None], 0.0, Q), np.where(bad[:, None], 0.0, V)
        return Q, V, bad

    def mass_matrices(self, q: np.ndarray) -> np.ndarray:
        """``(S, n, n)`` inertia matrices ``B(q)`` (a buffer view) from ``pin.crba``."""
        Q = np.asarray(q, dtype=float)
        self._grow(Q.shape[0])
        pm, d, M = self.model.pin_model, self._data, self._M
        for s in range(Q.shape[0]):
            M[s] = pin.crba(pm, d, Q[s])
        M = M[: Q.shape[0]]
        iu, ju = self._iu
        M[:, ju, iu] = M[:, iu, ju]  # crba fills the upper triangle
        return M

    def energies(self, q: np.ndarray, q_dot: np.ndarray, M: np.ndarray | None = None) -> np.ndarray:
        """Eq. 46 for all links: ``(S, L)`` J (a buffer view). ``M`` may pass ``B(q)``."""
        Q, V, bad = self._inputs(q, q_dot)
        return self._energies(V, self.mass_matrices(Q) if M is None else M, bad)

    def _energies(self, V: np.ndarray, M: np.ndarray, bad: np.ndarray) -> np.ndarray:
        S = V.shape[0]
        self._grow(S)
        w = V[:, None, :] * self._maskf[None]  # (S, L, n): E_i q_dot
        T = self._T[:S]
        np.einsum("sli,sli->sl", np.matmul(w, M), w, out=T)
        T *= 0.5
        T[bad] = np.inf
        return T

    def evaluate(
        self, q: np.ndarray, q_dot: np.ndarray, ends: np.ndarray | None = None
    ) -> LinkSamples:
        """Energies, capsule ends and link twists at samples ``q, q_dot (S, n)``.

        ``ends (S, L, 2, 3)``: world capsule ends at the samples when the caller already has
        them (e.g. from :meth:`RobotOccupancy.link_ends`); computed otherwise.
        """
        Q, V, bad = self._inputs(q, q_dot)
        S = Q.shape[0]
        self._grow(S)
        pm, d = self.model.pin_model, self._data
        M, J = self._M[:S], self._J[:S]
        for s in range(S):
            M[s] = pin.crba(pm, d, Q[s])
            J[s] = pin.computeJointJacobians(pm, d, Q[s])  # world frame, at the world origin
        iu, ju = self._iu
        M[:, ju, iu] = M[:, iu, ju]  # crba fills the upper triangle
        T = self._energies(V, M, bad)
        if ends is None:
            ends = self._occ.link_ends(Q)
            ends[bad] = np.nan
        # Twist of link i (base axes, at the base origin): sum over its supporting joints.
        tw = np.matmul(J * V[:, None, :], self._maskf.T)  # (S, 6, L)
        v, w_b = tw[:, :3], tw[:, 3:]
        p1 = ends[:, :, 0, :].transpose(0, 2, 1)  # (S, 3, L) world
        if not self._identity:
            p1 = np.matmul(self._R_wb.T, p1 - self._t_wb[:, None])  # base frame
        v = v + np.stack(  # + w x p1: velocity of the point p1
            [
                w_b[:, 1] * p1[:, 2] - w_b[:, 2] * p1[:, 1],
                w_b[:, 2] * p1[:, 0] - w_b[:, 0] * p1[:, 2],
                w_b[:, 0] * p1[:, 1] - w_b[:, 1] * p1[:, 0],
            ],
            axis=1,
        )
        if not self._identity:
            v, w_b = np.matmul(self._R_wb, v), np.matmul(self._R_wb, w_b)
        pd, w = self._pd[:S], self._w[:S]
        np.copyto(pd, v.transpose(0, 2, 1))
        np.copyto(w, w_b.transpose(0, 2, 1))
        if bad.any():
            pd[bad] = np.nan
            w[bad] = np.nan
        return LinkSamples(T, ends, pd, w)
