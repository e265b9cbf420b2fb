"""Plain-numpy references of the JSSA filter's compiled parts (Liu et al. 2022 eq. 9-14): the
one-constraint projection (compiled: ``jssa_kernels.project_halfspace_box``), the sliding
correction of ``d''`` (``jssa_kernels.sliding_terms``) and the linearised constraint
(``jssa_kernels.constraint_terms``). The mathematics is in the docstrings of
:mod:`sara_app.safety.jssa_qp` and :mod:`sara_app.safety.jssa_index`. Production never runs them.
"""

from __future__ import annotations

import numpy as np

from sara_app.safety.jssa_index import (
    _INTERIOR,
    _TINY_M,
    _dot,
    index_gradient,
    index_terms,
    predict_delta,
    safety_index,
)
from sara_app.safety.jssa_qp import FEAS_TOL


def project_halfspace_box(
    u0: np.ndarray,
    w: np.ndarray,
    g: np.ndarray,
    b: float,
    lo: np.ndarray,
    hi: np.ndarray,
) -> tuple[np.ndarray, float, bool]:
    """Exact solution of the one-constraint projection: ``(u (n,), mu, feasible)``.

    ``mu`` is the multiplier of ``g . u <= b``. When infeasible, ``u`` is the box point that
    minimises ``g . u`` (the least violating one) and ``mu = inf``."""
    u_box = np.clip(u0, lo, hi)
    if float(g @ u_box) <= b:
        return u_box, 0.0, True
    u_min = np.where(g > 0.0, lo, hi)
    if float(g @ u_min) > b + FEAS_TOL * max(1.0, abs(b)):
        return u_min, float("inf"), False
    nz = g != 0.0
    ratio = w[nz] / g[nz]
    bp = np.concatenate([(u0[nz] - hi[nz]) * ratio, (u0[nz] - lo[nz]) * ratio])
    bp = np.unique(bp[bp > 0.0])  # sorted
    # f at every breakpoint: (B, n) -> (B,)
    U = np.clip(u0[None, :] - bp[:, None] * (g / w)[None, :], lo, hi)
    f = U @ g
    k = int(np.searchsorted(-f, -b, side="left"))  # first breakpoint with f <= b
    if k >= len(bp):  # only round-off can get here (u_min was feasible)
        return u_min, float(bp[-1]) if len(bp) else 0.0, True
    mu_lo, f_lo = (0.0, float(g @ u_box)) if k == 0 else (float(bp[k - 1]), float(f[k - 1]))
    mu_hi, f_hi = float(bp[k]), float(f[k])
    mu = mu_hi if f_lo == f_hi else mu_lo + (f_lo - b) * (mu_hi - mu_lo) / (f_lo - f_hi)
    u = np.clip(u0 - mu * g / w, lo, hi)
    return u, mu, True


def sliding_correction(
    dp: np.ndarray,
    dv: np.ndarray,
    axis_r: np.ndarray,
    axis_r_dot: np.ndarray,
    axis_o: np.ndarray,
    axis_o_dot: np.ndarray,
    s: np.ndarray,
    t: np.ndarray,
) -> np.ndarray:
    """``slide (K,)`` m^2/s^2 (see the module notes) of pairs of closest axis points: relative
    position ``dp`` and velocity ``dv`` ``(K, 3)``, axis vectors (end minus start) of the robot
    and the other capsule and their rates ``(K, 3)``, closest-point parameters ``s, t (K,)``."""
    f1 = _dot(dv, axis_r) + _dot(dp, axis_r_dot)
    f2 = -(_dot(dv, axis_o) + _dot(dp, axis_o_dot))
    h11, h22, h12 = _dot(axis_r, axis_r), _dot(axis_o, axis_o), -_dot(axis_r, axis_o)
    act_s = (s > _INTERIOR) & (s < 1.0 - _INTERIOR) & (h11 > _TINY_M**2)
    act_t = (t > _INTERIOR) & (t < 1.0 - _INTERIOR) & (h22 > _TINY_M**2)
    det = h11 * h22 - h12 * h12
    both = act_s & act_t & (det > 1e-9 * h11 * h22)
    one_s = act_s & ~both
    one_t = act_t & ~act_s
    with np.errstate(divide="ignore", invalid="ignore"):
        c2 = (h22 * f1 * f1 - 2.0 * h12 * f1 * f2 + h11 * f2 * f2) / det
        cs, ct = f1 * f1 / h11, f2 * f2 / h22
    out = np.where(both, c2, 0.0)
    out = np.where(one_s, cs, out)
    return np.maximum(np.where(one_t, ct, out), 0.0)


def linear_constraints(
    p_r: np.ndarray,
    v_r: np.ndarray,
    a_r: np.ndarray,
    c_r: np.ndarray,
    J_r: np.ndarray,
    p_o: np.ndarray,
    v_o: np.ndarray,
    r_sum: np.ndarray,
    tau: float,
    d_min: float,
    lam1: float,
    lam2: float,
    slide: np.ndarray | float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Linearised ``phi_{k+1}(u) ~ phi0 + g . u`` (eq. 13): ``phi0 (K,)`` and ``g (K, n)``.

    ``J_r (K, 3, n)`` is the robot point's Jacobian; ``slide (K,)`` the sliding correction."""
    dp, dv, da = predict_delta(p_r, v_r, a_r, c_r, p_o, v_o, tau)
    d, g_p, g_v, g_a = index_gradient(dp, dv, da, r_sum, lam1, lam2, slide)
    d_, d_dot, d_ddot = index_terms(dp, dv, da, r_sum, slide)
    phi0 = safety_index(d_, d_dot, d_ddot, d_min, lam1, lam2)
    w = (tau**3 / 6.0) * g_p + (tau * tau / 2.0) * g_v + tau * g_a  # (K, 3)
    g = np.einsum("ki,kin->kn", w, J_r)
    return phi0, g
