"""Link kinetic energies (Thumm et al. 2024 Sec. VII, eq. 44-48) and link twists at trajectory
samples.

For a link carried by joint ``m`` (pinocchio's parent joint of the link frame), the energy a
contact with it can transfer is (eq. 46)::

    T_i(q, q_dot) = 1/2 q_dot^T E_i B(q) E_i q_dot,

``B`` the joint-space inertia matrix (``pin.crba``; here the compiled CRBA of
:mod:`sara_app.robot.crba_kernels`) and ``E_i`` the diagonal 0/1 matrix that keeps
the joints supporting joint ``m`` (for a serial chain the joints ``1..m``). The base link has
``T = 0``; the last link's ``T`` is the robot's whole kinetic energy ``1/2 q_dot^T B q_dot``.
Eq. 47-48 take the larger energy at the two ends of each interval (:func:`interval_energy_J`);
that misses the energy between the samples (a stop starts with ``s'' > 0``, so the path speed
peaks INSIDE the first failsafe interval: seen in closed loop 5 % above a threshold). The sound
interval energies used by the PFL check:

- along a path (``q' = dq/ds s'``, the shielded trajectory): :func:`path_interval_energy_J`,
  ``1/2 (1 + G_MARGIN) max s'^2 max(g(k), g(k+1))`` with the EXACT path-speed peak of the
  interval (``ShieldedTrajectory.sd_max``) and the configuration factor ``g_i = q'^T E_i B E_i q'``
  (``q' = dq/ds``) at the interval ends;
- any sampled trajectory with a bound on ``|q''|``: :func:`bounded_interval_energy_J` (the
  velocity stays within ``|q''| dt / 2`` of the nearer end sample; triangle inequality in the
  energy norm).

Remaining shortcut (named, as DESIGN.md asks): the inertia matrix ``B(q)`` (and ``g``) is
sampled at the interval ends, with the relative margin :data:`G_MARGIN` measured on shielded
trajectories (``tests/test_pfl_shield.py`` checks it against dense sampling).

:class:`LinkMotion` also returns, at the same samples, the world-frame velocity of each link
capsule's first end ``p1`` and the link's angular velocity ``omega`` (the inputs of Thumm et al.
2024 Thm VI.1, eq. 25). Units: J, m/s, rad/s; frames: world (``model.T_world_base`` applied).

Bad input never raises on the hot path: a sample with a non-finite ``q`` or ``q_dot`` gets
``T = inf`` and NaN velocities, which every predicate downstream treats as unsafe.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, types

from sara_app.errors import InputError, ParameterError
from sara_app.kernel_types import RO1 as _RO1
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import RO3 as _RO3
from sara_app.kernel_types import RO4 as _RO4
from sara_app.kernel_types import ROB1 as _ROB1
from sara_app.kernel_types import ROI1 as _ROI1
from sara_app.kernel_types import W2 as _W2
from sara_app.kernel_types import W3 as _W3
from sara_app.robot.crba_kernels import CompiledCrba
from sara_app.robot.model import RobotModel
from sara_app.robot.occupancy import RobotOccupancy


@dataclass(frozen=True)
class LinkSamples:
    """Link quantities at ``S`` samples (views into the owner's buffers; copy to keep).

    ``energy_J (S, L)``; ``ends (S, L, 2, 3)`` world capsule ends (m); ``p1_dot (S, L, 3)``
    velocity of ``ends[..., 0, :]`` (m/s); ``omega (S, L, 3)`` link angular velocity (rad/s);
    ``g_J (S, L)`` the quadratic form ``V^T E_i B E_i V`` of the given velocity direction ``V``
    (``2 energy_J`` for plain joint velocities; the configuration factor for ``V = dq/ds``).
    """

    energy_J: np.ndarray
    ends: np.ndarray
    p1_dot: np.ndarray
    omega: np.ndarray
    g_J: np.ndarray


def support_mask(model: RobotModel) -> np.ndarray:
    """``(L, n)`` bool: joint ``j`` supports (moves) link ``i``; the diagonal of ``E_i``."""
    pm = model.pin_model
    mask = np.zeros((model.n_links, model.n_dof), dtype=bool)
    for i, fid in enumerate(model._frame_ids):
        m = int(pm.frames[fid].parentJoint)
        for jid in pm.supports[m].tolist()[1:]:
            mask[i, pm.idx_vs[jid]] = True
    return mask


G_MARGIN = 1e-3
"""Relative margin on the configuration factor sampled at the interval ends (the inertia
matrix along the short path stretch of one interval). Measured: over 1620 intervals of random
shielded trajectories (Panda, blends, caps, stops), densely sampled energies exceeded the bound
without margin by at most 3e-5 relative (eq. 47-48's end samples alone: by up to 20 %)."""


def interval_energy_J(energy_J: np.ndarray) -> np.ndarray:
    """Eq. 47-48: ``(K+1, L)`` sample energies -> ``(K, L)`` max of both interval ends (the
    paper's form; it misses energy peaks between the samples, see the module notes)."""
    return np.maximum(energy_J[:-1], energy_J[1:])


@njit(types.void(_RO2, _RO2, _RO1, _RO1, _W2), cache=True)
def path_energy_kernel(
    g: np.ndarray, E: np.ndarray, sd: np.ndarray, sd_max: np.ndarray, out: np.ndarray
) -> None:
    """:func:`path_interval_energy_J` into ``out (K, L)``; any NaN input gives ``inf``."""
    K, L = out.shape
    c = 0.5 * (1.0 + G_MARGIN)
    for k in range(K):
        m = max(abs(sd[k]), abs(sd[k + 1]))
        if sd_max[k] > m:
            m = sd_max[k]
        bad_k = sd[k] != sd[k] or sd[k + 1] != sd[k + 1] or sd_max[k] != sd_max[k]
        for i in range(L):
            ga, gb = g[k, i], g[k + 1, i]
            ea, eb = E[k, i], E[k + 1, i]
            if bad_k or ga != ga or gb != gb or ea != ea or eb != eb:
                out[k, i] = math.inf
                continue
            v = c * (m * m) * max(ga, gb)
            out[k, i] = max(v, ea, eb)


def path_interval_energy_J(
    g_J: np.ndarray, energy_J: np.ndarray, sd: np.ndarray, sd_max: np.ndarray
) -> np.ndarray:
    """Link energy bound per interval ``(K, L)`` (J) for a motion along a path: ``1/2 (1 +
    G_MARGIN) m_k^2 max(g(k), g(k+1))``, ``m_k`` the largest ``|s'|`` over the interval
    (``sd (K+1,)`` at the samples, ``sd_max (K,)`` the exact peaks:
    ``ShieldedTrajectory.sd_max``), ``g_J (K+1, L)`` the configuration factors
    ``q'^T E_i B E_i q'`` (``q' = dq/ds``, :meth:`LinkMotion.evaluate_path`), and at least the
    sample energies ``energy_J (K+1, L)``. A NaN anywhere gives ``inf`` for the entry (unsafe
    wherever contact is possible)."""
    g = np.asarray(g_J, dtype=np.float64)
    E = np.asarray(energy_J, dtype=np.float64)
    sd = np.asarray(sd, dtype=np.float64)
    sd_max = np.asarray(sd_max, dtype=np.float64)
    K = sd_max.shape[0] if sd_max.ndim == 1 else -1
    if g.ndim != 2 or g.shape[0] != K + 1 or E.shape != g.shape or sd.shape != (K + 1,):
        raise InputError(
            f"g_J {g.shape}, energy_J {E.shape}, sd {sd.shape}, sd_max {sd_max.shape}: "
            "expected (K+1, L), (K+1, L), (K+1,), (K,)"
        )
    out = np.empty((K, g.shape[1]))
    path_energy_kernel(g, E, sd, sd_max, out)
    return out


@njit(types.void(_RO3, _RO2, _RO2, _RO2, _RO1, _W2), cache=True)
def _bounded_energy_kernel(
    M: np.ndarray,
    mask: np.ndarray,
    E: np.ndarray,
    delta: np.ndarray,
    scale: np.ndarray,
    out: np.ndarray,
) -> None:
    """:func:`bounded_interval_energy_J` into ``out (K, L)`` from the inertia matrices ``M
    (K+1, n, n)`` (upper triangle read), supports ``mask (L, n)``, sample energies ``E (K+1,
    L)`` and velocity deviations ``delta (K, n)``; ``scale (1,)`` = 1 + G_MARGIN. NaN: inf."""
    K, L = out.shape
    n = M.shape[1]
    for k in range(K):
        for i in range(L):
            best = 0.0
            bad = False
            for e in (k, k + 1):
                r2 = 0.0  # delta^T |E_i B E_i| delta
                for a in range(n):
                    if mask[i, a] == 0.0:
                        continue
                    da = abs(delta[k, a])
                    r2 += M[e, a, a] * da * da
                    for b in range(a + 1, n):
                        if mask[i, b] != 0.0:
                            r2 += 2.0 * abs(M[e, a, b]) * da * abs(delta[k, b])
                x = math.sqrt(2.0 * E[e, i]) + math.sqrt(r2)
                v = 0.5 * x * x
                if v != v:
                    bad = True
                elif v > best:
                    best = v
            out[k, i] = math.inf if bad else best * scale[0]


def bounded_interval_energy_J(
    motion: LinkMotion, q: np.ndarray, energy_J: np.ndarray, qdd_bound: np.ndarray, dt: np.ndarray
) -> np.ndarray:
    """Link energy bound per interval ``(K, L)`` (J) for any sampled joint trajectory: ``q
    (K+1, n)``, its sample energies ``energy_J (K+1, L)`` (:meth:`LinkMotion.evaluate`), a
    rigorous bound ``qdd_bound (K, n)`` on ``|q''|`` over each interval and the interval
    lengths ``dt (K,)``. On the half interval next to each end the velocity lies within
    ``delta = qdd_bound dt / 2`` of that end's, so (triangle inequality in the energy norm
    ``|x|_A = sqrt(x^T A x)``, ``A = E_i B E_i``) ``sqrt(2 T) <= sqrt(2 T_end) + sqrt(delta^T
    |A| delta)``; the larger end bound, times ``1 + G_MARGIN`` (``B`` sampled at the ends).
    The inertia matrices come from ``motion`` (its buffer)."""
    Q = np.asarray(q, dtype=np.float64)
    E = np.asarray(energy_J, dtype=np.float64)
    qdd = np.asarray(qdd_bound, dtype=np.float64)
    dt = np.asarray(dt, dtype=np.float64)
    K = dt.shape[0] if dt.ndim == 1 else -1
    n, L = motion.n_dof, motion.n_links
    if Q.shape != (K + 1, n) or E.shape != (K + 1, L) or qdd.shape != (K, n):
        raise InputError(
            f"q {Q.shape}, energy_J {E.shape}, qdd_bound {qdd.shape}, dt {dt.shape}: expected "
            f"({K + 1}, {n}), ({K + 1}, {L}), ({K}, {n}), (K,)"
        )
    M = motion._crba(np.where(np.isfinite(Q), Q, 0.0))
    delta = qdd * (0.5 * dt)[:, None]
    out = np.empty((K, L))
    _bounded_energy_kernel(M, motion._maskf, E, delta, np.array([1.0 + G_MARGIN]), out)
    return out


@njit(
    types.void(_RO2, _RO1, _RO3, _RO2, _RO4, _RO2, _ROI1, _RO4, _ROB1, _W2, _W2, _W3, _W3),
    cache=True,
)
def energy_twist_kernel(
    V: np.ndarray,
    scale: np.ndarray,
    M: np.ndarray,
    mask: np.ndarray,
    H: np.ndarray,
    axes: np.ndarray,
    v_index: np.ndarray,
    ends: np.ndarray,
    bad: np.ndarray,
    G: np.ndarray,
    T: np.ndarray,
    pd: np.ndarray,
    w: np.ndarray,
) -> None:
    """Eq. 46 and the link twists at ``S`` samples of the joint velocity ``scale[s] V[s]``.
    ``V (S, n)`` joint velocity directions, ``scale (S,)`` (``1`` for plain velocities; the
    path speed ``s'`` when ``V = dq/ds``), ``M (S, n, n)`` inertia matrices (upper triangle
    read), ``mask (L, n)`` 0/1 supports (velocity order); ``H (S, n+1, 4, 4)`` world joint
    frames and ``axes (n, 3)`` joint axes in them (kinematic order, ``v_index`` maps to the
    velocity order); ``ends (S, L, 2, 3)``. Writes ``G (S, L)`` = ``V^T E_i M E_i V``, ``T =
    scale^2 G / 2`` and, for the capsule end ``p1 = ends[..., 0, :]``, ``pd = sum_j qd_j a_j x
    (p1 - o_j)`` and ``w = sum_j qd_j a_j`` over the supporting joints ``j`` (world axis
    ``a_j``, origin ``o_j``, ``qd = scale V``), ``(S, L, 3)``. ``bad`` samples get ``G = T =
    inf`` and NaN twists."""
    S, n = V.shape
    L = mask.shape[0]
    wv = np.empty(n)
    ao = np.empty((n, 6))  # world axis and origin per joint (kinematic order)
    for s in range(S):
        sc = scale[s]
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
            if bad[s]:
                G[s, i] = T[s, i] = math.inf
            else:
                G[s, i] = acc
                T[s, i] = 0.5 * acc if sc == 1.0 else 0.5 * (sc * sc) * acc
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
                qd = V[s, c] * sc
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

    Built once per model (masks, buffers grown on demand). Not
    thread-safe. Typical use per control cycle with a shielded trajectory ``traj``::

        samples = motion.evaluate_path(traj.q, traj.dq, traj.sd)   # (K+1, ...) arrays
        T_interval = path_interval_energy_J(samples.g_J, samples.energy_J, traj.sd, traj.sd_max)
    """

    def __init__(self, model: RobotModel, occupancy: RobotOccupancy | None = None) -> None:
        self.model = model
        self.n_dof, self.n_links = model.n_dof, model.n_links
        self.mask = support_mask(model)
        self.mask.flags.writeable = False
        self._maskf = self.mask.astype(float)
        self._occ = occupancy or RobotOccupancy(model)
        pm = model.pin_model
        self._v_index = np.array([pm.idx_vs[j] for j in range(1, pm.njoints)], dtype=np.int64)
        crba = CompiledCrba(pm)
        if not crba.supported:
            raise ParameterError(
                f"robot {model.name!r}: link energies need the compiled CRBA, which does not "
                f"support this model ({crba.reason})"
            )
        self._compiled_crba = crba
        self._cap = 0
        self._grow(16)
        self._clean = np.zeros(0, dtype=bool)

    @property
    def occupancy(self) -> RobotOccupancy:
        """The kinematics it evaluates the capsule ends and joint frames with."""
        return self._occ

    @property
    def compiled_crba(self) -> CompiledCrba:
        """The compiled CRBA (:mod:`sara_app.robot.crba_kernels`) that fills the inertia
        matrices."""
        return self._compiled_crba

    def support_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(mask (L, n) float 0/1, v_index (n,))`` of :func:`energy_twist_kernel`: the joints
        supporting each link (velocity order) and each joint's velocity index (kinematic
        order)."""
        return self._maskf, self._v_index

    def _grow(self, S: int) -> None:
        if S <= self._cap:
            return
        n, L = self.n_dof, self.n_links
        self._cap = S
        self._M = np.zeros((S, n, n))
        self._T = np.zeros((S, L))
        self._G = np.zeros((S, L))
        self._ones = np.ones(S)
        self._ones.flags.writeable = False
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
        """Inertia matrices ``(S, n, n)`` at ``Q (S, n)`` float64 into the buffer (a view)."""
        S = Q.shape[0]
        self._grow(S)
        M = self._M[:S]
        self._compiled_crba.compute(Q, M)
        return M

    def mass_matrices(self, q: np.ndarray) -> np.ndarray:
        """``(S, n, n)`` inertia matrices ``B(q)`` (a buffer view) at ``q (S, n)``; a
        non-finite ``q`` row gives non-finite entries (no exception)."""
        Q = np.asarray(q, dtype=np.float64)
        if Q.ndim != 2 or Q.shape[1] != self.n_dof:
            raise InputError(f"q has shape {Q.shape}; expected (S, {self.n_dof}) joint positions")
        return self._crba(Q)

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

    def evaluate_path(
        self, q: np.ndarray, dq_ds: np.ndarray, sd: np.ndarray, ends: np.ndarray | None = None
    ) -> LinkSamples:
        """:meth:`evaluate` for a motion along a path: joint velocity ``dq_ds (S, n)`` times
        the path speed ``sd (S,)``; ``g_J`` are then the configuration factors ``q'^T E_i B
        E_i q'`` (``q' = dq/ds``) of :func:`path_interval_energy_J`. A non-finite ``sd``
        marks its sample bad (infinite energy, NaN twists)."""
        sd = np.asarray(sd, dtype=np.float64)
        if sd.shape != (np.shape(q)[0],):
            raise InputError(f"sd has shape {sd.shape}; expected ({np.shape(q)[0]},)")
        return self._run(q, dq_ds, None, ends, sd)

    def _run(
        self,
        q: np.ndarray,
        q_dot: np.ndarray,
        M: np.ndarray | None,
        ends: np.ndarray | None,
        scale: np.ndarray | None = None,
    ) -> LinkSamples:
        """The inertia matrices (:meth:`_crba`, unless ``M`` is given), then one compiled pass
        (:func:`energy_twist_kernel`) over the vectorised kinematics of
        :class:`RobotOccupancy` for the energies and twists."""
        Q, V, bad = self._inputs(q, q_dot)
        S = Q.shape[0]
        self._grow(S)
        if scale is None:
            scale = self._ones[:S]
        elif not math.isfinite(float(scale.sum())):
            bad = bad | ~np.isfinite(scale)
            scale = np.where(bad, 0.0, scale)
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
        G, T, pd, w = self._G[:S], self._T[:S], self._pd[:S], self._w[:S]
        energy_twist_kernel(
            V, scale, np.asarray(M, dtype=np.float64), self._maskf, H, self._occ._axes,
            self._v_index, np.asarray(ends, dtype=np.float64), bad, G, T, pd, w,
        )  # fmt: skip
        return LinkSamples(T, ends, pd, w, G)
