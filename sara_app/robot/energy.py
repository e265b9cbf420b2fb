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

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin
from numba import njit, types

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


_f8 = types.float64
_RO1, _RO2, _RO3, _RO4 = (types.Array(_f8, d, "A", readonly=True) for d in (1, 2, 3, 4))
_ROI1 = types.Array(types.int64, 1, "A", readonly=True)
_ROB1 = types.Array(types.boolean, 1, "A", readonly=True)
_W2, _W3 = types.Array(_f8, 2, "A"), types.Array(_f8, 3, "A")


@njit(types.void(_RO2, _RO3, _RO2, _RO4, _RO2, _ROI1, _RO4, _ROB1, _W2, _W3, _W3), cache=True)
def _energy_twist_kernel(
    V: np.ndarray,
    M: np.ndarray,
    mask: np.ndarray,
    H: np.ndarray,
    axes: np.ndarray,
    v_index: np.ndarray,
    ends: np.ndarray,
    bad: np.ndarray,
    T: np.ndarray,
    pd: np.ndarray,
    w: np.ndarray,
) -> None:
    """Eq. 46 and the link twists at ``S`` samples. ``V (S, n)`` joint velocities, ``M (S, n,
    n)`` inertia matrices (upper triangle read), ``mask (L, n)`` 0/1 supports (velocity
    order); ``H (S, n+1, 4, 4)`` world joint frames and ``axes (n, 3)`` joint axes in them
    (kinematic order, ``v_index`` maps to the velocity order); ``ends (S, L, 2, 3)``. Writes
    ``T (S, L)`` and, for the capsule end ``p1 = ends[..., 0, :]``, ``pd = sum_j qd_j a_j x (p1 -
    o_j)`` and ``w = sum_j qd_j a_j`` over the supporting joints ``j`` (world axis ``a_j``,
    origin ``o_j``), ``(S, L, 3)``. ``bad`` samples get ``T = inf`` and NaN twists."""
    S, n = V.shape
    L = mask.shape[0]
    wv = np.empty(n)
    ao = np.empty((n, 6))  # world axis and origin per joint (kinematic order)
    for s in range(S):
        for i in range(L):
            for a in range(n):
                wv[a] = V[s, a] * mask[i, a]
            acc = 0.0
            for a in range(n):
                if wv[a] != 0.0:
                    row = M[s, a, a] * wv[a]
                    for b in range(a + 1, n):
                        row += 2.0 * M[s, a, b] * wv[b]
                    acc += wv[a] * row
            T[s, i] = math.inf if bad[s] else 0.5 * acc
        for j in range(n):
            for r in range(3):
                ao[j, r] = (
                    H[s, j + 1, r, 0] * axes[j, 0]
                    + H[s, j + 1, r, 1] * axes[j, 1]
                    + H[s, j + 1, r, 2] * axes[j, 2]
                )
                ao[j, 3 + r] = H[s, j + 1, r, 3]
        for i in range(L):
            px, py, pz = ends[s, i, 0, 0], ends[s, i, 0, 1], ends[s, i, 0, 2]
            vx = vy = vz = wx = wy = wz = 0.0
            for j in range(n):
                c = v_index[j]
                if mask[i, c] == 0.0:
                    continue
                qd = V[s, c]
                ax, ay, az = ao[j, 0], ao[j, 1], ao[j, 2]
                rx, ry, rz = px - ao[j, 3], py - ao[j, 4], pz - ao[j, 5]
                vx += qd * (ay * rz - az * ry)
                vy += qd * (az * rx - ax * rz)
                vz += qd * (ax * ry - ay * rx)
                wx += qd * ax
                wy += qd * ay
                wz += qd * az
            if bad[s]:
                vx = vy = vz = wx = wy = wz = math.nan
            pd[s, i, 0], pd[s, i, 1], pd[s, i, 2] = vx, vy, vz
            w[s, i, 0], w[s, i, 1], w[s, i, 2] = wx, wy, wz


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
        self._iu = np.triu_indices(self.n_dof, 1)
        pm = model.pin_model
        self._v_index = np.array([pm.idx_vs[j] for j in range(1, pm.njoints)], dtype=np.int64)
        self._cap = 0
        self._grow(16)
        self._clean = np.zeros(0, dtype=bool)

    def _grow(self, S: int) -> None:
        if S <= self._cap:
            return
        n, L = self.n_dof, self.n_links
        self._cap = S
        self._M = np.zeros((S, n, n))
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
        if math.isfinite(float(Q.sum()) + float(V.sum())):  # the usual case: two reductions
            return Q, V, self._no_bad(Q.shape[0])
        bad = ~(np.isfinite(Q).all(axis=1) & np.isfinite(V).all(axis=1))
        Q, V = np.where(bad[:, None], 0.0, Q), np.where(bad[:, None], 0.0, V)
        return Q, V, bad

    def _no_bad(self, S: int) -> np.ndarray:
        """A read-only all-False ``(S,)`` mask (shared)."""
        if self._clean.shape[0] < S:
            self._clean = np.zeros(S, dtype=bool)
            self._clean.flags.writeable = False
        return self._clean[:S]

    def _crba(self, Q: np.ndarray) -> np.ndarray:
        """``pin.crba`` per sample into the buffer: ``(S, n, n)``, upper triangle filled."""
        self._grow(Q.shape[0])
        pm, d, M = self.model.pin_model, self._data, self._M
        for s in range(Q.shape[0]):
            M[s] = pin.crba(pm, d, Q[s])
        return M[: Q.shape[0]]

    def mass_matrices(self, q: np.ndarray) -> np.ndarray:
        """``(S, n, n)`` inertia matrices ``B(q)`` (a buffer view) from ``pin.crba``."""
        M = self._crba(np.asarray(q, dtype=float))
        iu, ju = self._iu
        M[:, ju, iu] = M[:, iu, ju]  # crba fills the upper triangle
        return M

    def energies(self, q: np.ndarray, q_dot: np.ndarray, M: np.ndarray | None = None) -> np.ndarray:
        """Eq. 46 for all links: ``(S, L)`` J (a buffer view). ``M`` may pass ``B(q)``."""
        return self._run(q, q_dot, M, None).energy_J

    def evaluate(
        self, q: np.ndarray, q_dot: np.ndarray, ends: np.ndarray | None = None
    ) -> LinkSamples:
        """Energies, capsule ends and link twists at samples ``q, q_dot (S, n)``.

        ``ends (S, L, 2, 3)``: world capsule ends at the samples when the caller already has
        them (e.g. from :meth:`RobotOccupancy.link_ends`); computed otherwise.
        """
        return self._run(q, q_dot, None, ends)

    def _run(
        self, q: np.ndarray, q_dot: np.ndarray, M: np.ndarray | None, ends: np.ndarray | None
    ) -> LinkSamples:
        """One ``pin.crba`` per sample (unless ``M`` is given), then one compiled pass
        (:func:`_energy_twist_kernel`) over the vectorised kinematics of
        :class:`RobotOccupancy` for the energies and twists."""
        Q, V, bad = self._inputs(q, q_dot)
        S = Q.shape[0]
        self._grow(S)
        if M is None:
            M = self._crba(Q)  # upper triangle; the kernel reads only that
        elif np.shape(M) != (S, self.n_dof, self.n_dof):
            raise InputError(
                f"M has shape {np.shape(M)}; expected ({S}, {self.n_dof}, {self.n_dof})"
            )
        H = self._occ._fk(Q)
        if ends is None:
            ends = self._occ._ends(H).copy()
            if bad.any():
                ends[bad] = np.nan
        elif np.shape(ends) != (S, self.n_links, 2, 3):
            raise InputError(
                f"ends has shape {np.shape(ends)}; expected ({S}, {self.n_links}, 2, 3)"
            )
        T, pd, w = self._T[:S], self._pd[:S], self._w[:S]
        _energy_twist_kernel(
            V, np.asarray(M, dtype=np.float64), self._maskf, H, self._occ._axes, self._v_index,
            np.asarray(ends, dtype=np.float64), bad, T, pd, w,
        )  # fmt: skip
        return LinkSamples(T, ends, pd, w)
