"""Compiled (numba) kernel of the JSSA point kinematics (:mod:`sara_app.safety.jssa_kinematics`).

At one or a few points per cycle numpy spends its time in per-call overhead (about 2 us per
array operation, some 60 operations); the same arithmetic as loops costs a few microseconds.
The mathematics is documented in :class:`~sara_app.safety.jssa_kinematics.PointKinematics` and
tested there against finite differences of simulated motion.

Compiled at import (explicit signature, ``cache=True``), never in a control loop.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from sara_app.kernel_types import F8 as _f8
from sara_app.kernel_types import RO1 as _R1
from sara_app.kernel_types import RO2 as _R2
from sara_app.kernel_types import RO3 as _R3
from sara_app.kernel_types import ROI1 as _I1
from sara_app.kernel_types import WC1 as _W1
from sara_app.kernel_types import WC2 as _W2
from sara_app.kernel_types import WC3 as _W3


@njit(cache=True)
def _vel_acc(
    V: np.ndarray, A: np.ndarray, k: int, li: int, px: float, py: float, pz: float
) -> tuple[float, float, float, float, float, float]:
    """``p' = V_lin + w x p`` and ``p'' = A_lin + A_ang x p + w x p'`` of point ``p`` (base
    frame) of link ``li`` at state ``k`` (``V, A (3, L, 6)``)."""
    wx, wy, wz = V[k, li, 3], V[k, li, 4], V[k, li, 5]
    vx = V[k, li, 0] + wy * pz - wz * py
    vy = V[k, li, 1] + wz * px - wx * pz
    vz = V[k, li, 2] + wx * py - wy * px
    bx, by, bz = A[k, li, 3], A[k, li, 4], A[k, li, 5]
    ax = A[k, li, 0] + by * pz - bz * py + wy * vz - wz * vy
    ay = A[k, li, 1] + bz * px - bx * pz + wz * vx - wx * vz
    az = A[k, li, 2] + bx * py - by * px + wx * vy - wy * vx
    return vx, vy, vz, ax, ay, az


@njit(types.void(_R3, _R3, _R2, _R2, _I1, _R2, _f8, _W2, _W2, _W2, _W3), cache=True)
def point_terms(
    V: np.ndarray,
    A: np.ndarray,
    J: np.ndarray,
    mask: np.ndarray,
    link_idx: np.ndarray,
    p_b: np.ndarray,
    h: float,
    v_out: np.ndarray,
    a_out: np.ndarray,
    c_out: np.ndarray,
    J_out: np.ndarray,
) -> None:
    """Base-frame velocity, acceleration, drift jerk ``(K, 3)`` and Jacobian ``(K, 3, n)`` of
    points ``p_b (K, 3)`` fixed in links ``link_idx (K,)``. ``V, A (3, L, 6)``: spatial velocity
    and acceleration per state (t, t + h, t - h) and link; ``J (6, n)`` the world Jacobian at
    ``t`` (rows linear, angular); ``mask (L, n)`` the joints that move each link."""
    K, n = p_b.shape[0], J.shape[1]
    for i in range(K):
        li = link_idx[i]
        px, py, pz = p_b[i, 0], p_b[i, 1], p_b[i, 2]
        vx, vy, vz, ax, ay, az = _vel_acc(V, A, 0, li, px, py, pz)
        v_out[i, 0], v_out[i, 1], v_out[i, 2] = vx, vy, vz
        a_out[i, 0], a_out[i, 1], a_out[i, 2] = ax, ay, az
        hh = 0.5 * h * h
        qx, qy, qz = px + hh * ax, py + hh * ay, pz + hh * az
        up = _vel_acc(V, A, 1, li, qx + h * vx, qy + h * vy, qz + h * vz)
        dn = _vel_acc(V, A, 2, li, qx - h * vx, qy - h * vy, qz - h * vz)
        c_out[i, 0] = (up[3] - dn[3]) / (2.0 * h)
        c_out[i, 1] = (up[4] - dn[4]) / (2.0 * h)
        c_out[i, 2] = (up[5] - dn[5]) / (2.0 * h)
        for j in range(n):
            m = mask[li, j]
            wx, wy, wz = J[3, j], J[4, j], J[5, j]
            # J_lin - p x J_ang
            J_out[i, 0, j] = m * (J[0, j] - (py * wz - pz * wy))
            J_out[i, 1, j] = m * (J[1, j] - (pz * wx - px * wz))
            J_out[i, 2, j] = m * (J[2, j] - (px * wy - py * wx))


_TINY_M = 1e-9  # as sara_app.safety.jssa_index


@njit(cache=True)
def _terms(
    dpx: float, dpy: float, dpz: float, dvx: float, dvy: float, dvz: float,
    dax: float, day: float, daz: float, r_sum: float, slide: float,
) -> tuple[float, float, float, float]:  # fmt: skip
    """``(D, d, d', d'')`` of one relative state (:func:`jssa_index.index_terms`)."""
    D = max(math.sqrt(dpx * dpx + dpy * dpy + dpz * dpz), _TINY_M)
    d1 = (dpx * dvx + dpy * dvy + dpz * dvz) / D
    N = dvx * dvx + dvy * dvy + dvz * dvz + dpx * dax + dpy * day + dpz * daz - slide
    return D, D - r_sum, d1, N / D - d1 * d1 / D


@njit(
    types.void(
        _R2, _R2, _R2, _R2, _R3, _R2, _R2, _R1, _R1, _f8, _f8, _f8, _f8,
        _W1, _W1, _W1, _W1, _W1, _W2,
    ),
    cache=True,
)  # fmt: skip
def constraint_terms(
    p_r: np.ndarray,
    v_r: np.ndarray,
    a_r: np.ndarray,
    c_r: np.ndarray,
    J_r: np.ndarray,
    p_o: np.ndarray,
    v_o: np.ndarray,
    r_sum: np.ndarray,
    slide: np.ndarray,
    tau: float,
    d_min: float,
    lam1: float,
    lam2: float,
    d: np.ndarray,
    d_dot: np.ndarray,
    d_ddot: np.ndarray,
    phi: np.ndarray,
    phi0: np.ndarray,
    g: np.ndarray,
) -> None:
    """Per pair ``k``: the current ``d, d', d'', phi`` and the linearised next index
    ``phi_{k+1}(u) ~ phi0 + g . u`` (``g (K, n)``); the arithmetic of
    :func:`sara_app.safety.jssa_index.index_terms`, :func:`~.safety_index` and
    the linearisation of eq. 13 (tested equal to ``tests/jssa_reference.py``)."""
    K, n = p_r.shape[0], J_r.shape[2]
    t2, t3 = tau * tau / 2.0, tau * tau * tau / 6.0
    dm2 = d_min * d_min
    for k in range(K):
        sl, rs = slide[k], r_sum[k]
        dp = p_r[k] - p_o[k]
        dv = v_r[k] - v_o[k]
        da = a_r[k]
        _, dk, d1, d2 = _terms(
            dp[0], dp[1], dp[2], dv[0], dv[1], dv[2], da[0], da[1], da[2], rs, sl
        )  # fmt: skip
        d[k], d_dot[k], d_ddot[k] = dk, d1, d2
        phi[k] = dm2 - dk * abs(dk) - lam1 * d1 - lam2 * d2
        # Delta: the next relative state at u = 0 (eq. 11)
        P = p_r[k] + tau * v_r[k] + t2 * a_r[k] + t3 * c_r[k] - (p_o[k] + tau * v_o[k])
        Vv = v_r[k] + tau * a_r[k] + t2 * c_r[k] - v_o[k]
        Aa = a_r[k] + tau * c_r[k]
        D, dn, e1, e2 = _terms(
            P[0], P[1], P[2], Vv[0], Vv[1], Vv[2], Aa[0], Aa[1], Aa[2], rs, sl
        )  # fmt: skip
        phi0[k] = dm2 - dn * abs(dn) - lam1 * e1 - lam2 * e2
        N = (
            Vv[0] * Vv[0] + Vv[1] * Vv[1] + Vv[2] * Vv[2]
            + P[0] * Aa[0] + P[1] * Aa[1] + P[2] * Aa[2] - sl
        )  # fmt: skip
        for j in range(n):
            g[k, j] = 0.0
        for i in range(3):
            ni = P[i] / D
            dd_dp = (Vv[i] - e1 * ni) / D
            ddd_dp = Aa[i] / D - N * ni / (D * D) - 2.0 * e1 * dd_dp / D + e1 * e1 * ni / (D * D)
            g_p = -2.0 * abs(dn) * ni - lam1 * dd_dp - lam2 * ddd_dp
            g_v = -lam1 * ni - lam2 * (2.0 * Vv[i] - 2.0 * e1 * ni) / D
            g_a = -lam2 * ni
            w = t3 * g_p + t2 * g_v + tau * g_a
            for j in range(n):
                g[k, j] += w * J_r[k, i, j]


@njit(types.float64(_R1, _R1, _R1, _f8, _R1, _R1, _f8, _W1), cache=True)
def project_halfspace_box(
    u0: np.ndarray,
    w: np.ndarray,
    g: np.ndarray,
    b: float,
    lo: np.ndarray,
    hi: np.ndarray,
    feas_tol: float,
    u: np.ndarray,
) -> float:
    """The one-constraint projection of :mod:`sara_app.safety.jssa_qp` (reference in tests; same
    algorithm: the root of the monotone piecewise-linear ``f(mu) = g . clip(u0 - mu g / w, lo,
    hi)``). Writes ``u`` and returns ``mu`` (``inf``: infeasible, ``u`` the least violating box
    point)."""
    n = u0.shape[0]
    f0 = 0.0
    for i in range(n):
        u[i] = min(max(u0[i], lo[i]), hi[i])
        f0 += g[i] * u[i]
    if f0 <= b:
        return 0.0
    fmin = 0.0
    for i in range(n):
        fmin += g[i] * (lo[i] if g[i] > 0.0 else hi[i])
    if fmin > b + feas_tol * max(1.0, abs(b)):
        for i in range(n):
            u[i] = lo[i] if g[i] > 0.0 else hi[i]
        return np.inf
    bp = np.empty(2 * n)
    m = 0
    for i in range(n):
        if g[i] != 0.0:
            r = w[i] / g[i]
            for x in ((u0[i] - hi[i]) * r, (u0[i] - lo[i]) * r):
                if x > 0.0:
                    bp[m] = x
                    m += 1
    bps = np.sort(bp[:m])
    mu_lo, f_lo = 0.0, f0
    for k in range(m):
        mu = bps[k]
        if k > 0 and mu == bps[k - 1]:
            continue
        f = 0.0
        for i in range(n):
            f += g[i] * min(max(u0[i] - mu * g[i] / w[i], lo[i]), hi[i])
        if f <= b:
            mu_hit = mu if f_lo == f else mu_lo + (f_lo - b) * (mu - mu_lo) / (f_lo - f)
            for i in range(n):
                u[i] = min(max(u0[i] - mu_hit * g[i] / w[i], lo[i]), hi[i])
            return mu_hit
        mu_lo, f_lo = mu, f
    # only round-off gets here (the box minimum was feasible)
    for i in range(n):
        u[i] = lo[i] if g[i] > 0.0 else hi[i]
    return bps[m - 1] if m > 0 else 0.0


_INTERIOR = 1e-9  # as sara_app.safety.jssa_index


@njit(types.void(_R2, _R2, _R2, _R2, _R2, _R2, _R1, _R1, _W1), cache=True)
def sliding_terms(
    dp: np.ndarray,
    dv: np.ndarray,
    axis_r: np.ndarray,
    omega_r: np.ndarray,
    axis_o: np.ndarray,
    axis_o_dot: np.ndarray,
    s: np.ndarray,
    t: np.ndarray,
    out: np.ndarray,
) -> None:
    """The sliding correction of :mod:`sara_app.safety.jssa_index` compiled, with the robot axis
    rate ``omega_r x axis_r`` (rigid link, angular velocity ``omega_r (K, 3)``). Writes ``out
    (K,)``."""
    for k in range(dp.shape[0]):
        ar, ao, ad = axis_r[k], axis_o[k], axis_o_dot[k]
        w = omega_r[k]
        rdx = w[1] * ar[2] - w[2] * ar[1]
        rdy = w[2] * ar[0] - w[0] * ar[2]
        rdz = w[0] * ar[1] - w[1] * ar[0]
        p, v = dp[k], dv[k]
        f1 = v[0] * ar[0] + v[1] * ar[1] + v[2] * ar[2] + p[0] * rdx + p[1] * rdy + p[2] * rdz
        f2 = -(
            v[0] * ao[0] + v[1] * ao[1] + v[2] * ao[2] + p[0] * ad[0] + p[1] * ad[1] + p[2] * ad[2]
        )
        h11 = ar[0] * ar[0] + ar[1] * ar[1] + ar[2] * ar[2]
        h22 = ao[0] * ao[0] + ao[1] * ao[1] + ao[2] * ao[2]
        h12 = -(ar[0] * ao[0] + ar[1] * ao[1] + ar[2] * ao[2])
        act_s = _INTERIOR < s[k] < 1.0 - _INTERIOR and h11 > _TINY_M * _TINY_M
        act_t = _INTERIOR < t[k] < 1.0 - _INTERIOR and h22 > _TINY_M * _TINY_M
        det = h11 * h22 - h12 * h12
        c = 0.0
        if act_s and act_t and det > 1e-9 * h11 * h22:
            c = (h22 * f1 * f1 - 2.0 * h12 * f1 * f2 + h11 * f2 * f2) / det
        elif act_s:
            c = f1 * f1 / h11
        elif act_t:
            c = f2 * f2 / h22
        out[k] = max(c, 0.0)
