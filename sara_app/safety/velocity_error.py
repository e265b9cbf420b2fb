"""Thm VI.2 of Thumm et al. 2024: a bound on the linearisation error of the projected point velocity
of every robot link over an interval (the ``eps_v`` of the velocity relaxation in
:mod:`sara_app.safety.contact`)."""

from __future__ import annotations

import numpy as np

from sara_app.errors import InputError
from sara_app.robot.model import RobotModel
from sara_app.safety.contact_kernels import jerk_coefficients

__all__ = ["VelocityErrorBound"]


class VelocityErrorBound:
    """Bound of ``|d^2/dt^2 (n . p_dot)|`` over all points of each link (Thm VI.2).

    ``eps_v = dt^2 / 8 * C_l`` (eq. 52: interpolation error of a C^2 function; Thumm et al. 2024 eq.
    27 prints ``dt / 8``, which is not dimensionally a speed). ``C_l`` bounds the jerk of every
    point of link ``l`` from joint speed, acceleration and jerk bounds. Two forms:

    - ``"spatial"`` (default, derived for 3-D revolute chains): angular velocity, acceleration
      and jerk bounds of each body propagate along the chain (``W_i = W + |qd_i|``, ``A_i = A +
      |qdd_i| + |qd_i| W``, ``B_i = B + |qddd_i| + 2 |qdd_i| W + |qd_i| (A + W^2)``: the
      derivatives of ``Omega_i = Omega_i-1 + qd_i a_i`` with the axis ``a_i`` turning with its
      parent), and a point ``s`` metres further on body ``i`` adds ``s (B_i + 3 A_i W_i +
      W_i^3)`` to the jerk (third derivative of ``s`` rotating with the body);
    - ``"paper"``: Thumm et al. 2024 eq. 27 (planar derivation, with the factor 2 of eq. 53 on the
    middle
      term), which omits the terms from turning axes. Kept for comparison.

    Lengths: ``d`` are the distances between consecutive joint origins along each link's chain
    (constant), the last one replaced by the reach of the link capsule from its joint origin.
    """

    def __init__(self, model: RobotModel) -> None:
        pm = model.pin_model
        self.n_links, self.n_dof = model.n_links, model.n_dof
        chains: list[list[int]] = []
        lengths: list[np.ndarray] = []
        for i, fid in enumerate(model._frame_ids):
            frame = pm.frames[fid]
            m = int(frame.parentJoint)
            chain = [int(j) for j in pm.supports[m].tolist()[1:]]
            ends_m = (
                model.capsules_local[i] @ frame.placement.rotation.T + frame.placement.translation
            )
            reach = float(np.max(np.linalg.norm(ends_m, axis=1))) + float(model.radius_m[i])
            d = [float(np.linalg.norm(pm.jointPlacements[c].translation)) for c in chain[1:]]
            chains.append([int(pm.idx_vs[j]) for j in chain])
            lengths.append(np.array(d + [reach]) if chain else np.zeros(0))
        self.chains, self.lengths = chains, lengths
        # Vectorised form: per joint (v index) its parent joint (-1: the base) and the lever
        # matrix D (n, L): D[c, i] = the length following joint c on link i's chain.
        self._parent = np.array(
            [
                int(pm.idx_vs[pm.parents[j]]) if pm.parents[j] > 0 else -1
                for j in range(1, pm.njoints)
            ],
            dtype=np.int64,
        )
        self._order = np.array([int(pm.idx_vs[j]) for j in range(1, pm.njoints)], dtype=np.int64)
        self._D = np.zeros((self.n_dof, self.n_links))
        for i, (chain, lever) in enumerate(zip(chains, lengths)):
            self._D[chain, i] = lever
        lim = model.limits
        self.C_limits = self.coefficients(lim.v_max, lim.a_max, lim.j_max)
        """``(L,)`` m/s^3 from the joint limits."""

    def kernel_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(order, parent, D)`` of :func:`~sara_app.safety.contact_kernels.jerk_coefficients`
        for kernels that call it themselves."""
        return self._order, self._parent, self._D

    def coefficients(
        self, qd: np.ndarray, qdd: np.ndarray, qddd: np.ndarray, form: str = "spatial"
    ) -> np.ndarray:
        """``C (..., L)`` from absolute joint bounds ``(..., n)`` (rad/s, rad/s^2, rad/s^3)."""
        qd, qdd, qddd = (np.asarray(x, dtype=float) for x in (qd, qdd, qddd))
        if form == "paper":
            qd, qdd, qddd = np.abs(qd), np.abs(qdd), np.abs(qddd)
            out = np.zeros(qd.shape[:-1] + (self.n_links,))
            for i, (chain, d) in enumerate(zip(self.chains, self.lengths)):
                out[..., i] = _paper_coefficient(chain, d, qd, qdd, qddd)
            return out
        # Bounds on |Omega|, |alpha|, |beta| of the body after each joint (parents first); a
        # point s metres further on body j adds s (|beta| + 3 |alpha||Omega| + |Omega|^3).
        shape = np.broadcast_shapes(qd.shape, qdd.shape, qddd.shape)
        qd, qdd, qddd = (np.broadcast_to(x, shape) for x in (qd, qdd, qddd))
        if qd.shape[-1:] != (self.n_dof,):
            raise InputError(f"joint bounds have shape {qd.shape}; expected (..., {self.n_dof})")
        lead = qd.shape[:-1]
        fd, fdd, fddd = (np.reshape(x, (-1, self.n_dof)) for x in (qd, qdd, qddd))
        out = np.empty((fd.shape[0], self.n_links))
        ones = np.ones(fd.shape[0])
        jerk_coefficients(fd, fdd, fddd, self._order, self._parent, self._D, ones, out)
        return out.reshape(lead + (self.n_links,))

    def eps_v(self, dt: np.ndarray, C: np.ndarray | None = None) -> np.ndarray:
        """``(K, L)`` m/s for interval lengths ``dt (K,)``; ``C`` defaults to the limits'."""
        C = self.C_limits if C is None else C
        return (np.asarray(dt, dtype=float) ** 2 / 8.0)[:, None] * C

    def eps_from_bounds(
        self, dt: np.ndarray, qd: np.ndarray, qdd: np.ndarray, qddd: np.ndarray
    ) -> np.ndarray:
        """``eps_v (K, L)`` from ``dt (K,)`` and joint bounds ``qd (K, n)``, ``qdd`` and
        ``qddd`` ``(K, n)`` or ``(n,)`` (the same on every interval): :meth:`eps_v` of
        :meth:`coefficients`, in one compiled pass."""
        dt = np.asarray(dt, dtype=np.float64)
        qd, qdd, qddd = (np.asarray(x, dtype=np.float64) for x in (qd, qdd, qddd))
        K, n = dt.shape[0] if dt.ndim == 1 else -1, self.n_dof
        qdd, qddd = (x.reshape(1, n) if x.shape == (n,) else x for x in (qdd, qddd))
        if (
            qd.shape != (K, n)
            or qdd.shape[1:] != (n,)
            or qdd.shape[0] not in (1, K)
            or (qddd.shape[1:] != (n,) or qddd.shape[0] not in (1, K))
        ):
            raise InputError(
                f"dt {dt.shape}, joint bounds {qd.shape}, {qdd.shape}, {qddd.shape}; expected "
                f"(K,), (K, {n}) and (K, {n}) or ({n},) twice"
            )
        out = np.empty((K, self.n_links))
        scale = dt * dt
        scale /= 8.0
        jerk_coefficients(qd, qdd, qddd, self._order, self._parent, self._D, scale, out)
        return out


def _paper_coefficient(
    chain: list[int], d: np.ndarray, qd: np.ndarray, qdd: np.ndarray, qddd: np.ndarray
) -> np.ndarray:
    """Thumm et al. 2024 eq. 27 bracket summed over k <= i along ``chain`` (i = segment index)."""
    total = np.zeros(qd.shape[:-1])
    if not chain:
        return total
    V = np.cumsum(qd[..., chain], axis=-1)  # sum_{j<=i} qd_j
    A = np.cumsum(qdd[..., chain], axis=-1)
    for i in range(len(chain)):
        k = chain[: i + 1]
        inner = qddd[..., k] + 2.0 * qdd[..., k] * V[..., i, None]
        inner = inner + qd[..., k] * (A[..., i, None] + V[..., i, None] ** 2)
        total = total + d[i] * inner.sum(axis=-1)
    return total
