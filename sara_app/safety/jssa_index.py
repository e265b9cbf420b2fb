"""JSSA safety index (seed 002 eq. 6, 12) and its linearised constraint (eq. 9-13).

All functions are batched over critical pairs ``K``. A pair's relative state is
``delta = [dp; dv; da]`` (robot point minus human/obstacle point, each ``(K, 3)``, world frame)
between the two capsule AXIS points; the surface distance is ``d = |dp| - r_sum`` with
``r_sum (K,)`` the two radii, so ``d', d''`` are those of ``|dp|``:

- ``d'  = n . dv`` with ``n = dp / |dp|``
- ``d'' = (|dv|^2 + dp . da) / |dp| - d'^2 / |dp|``                      (eq. 12)
- ``phi = d_min^2 - d |d| - lambda_1 d' - lambda_2 d''``                    (eq. 6)

``d |d|`` replaces the paper's ``d^2`` so that ``phi`` keeps growing with penetration depth
(``d < 0``); both define the same set ``d >= d_min`` (``d_min > 0``).

Discrete prediction (eq. 8-11): with the jerk-controlled robot point
``M_{k+1} = A(tau) M_k + B(tau) (J u + c)`` and the other point under the constant-velocity
model (eq. 4; static obstacles: eq. 2), ``delta_{k+1} = Delta + B(tau) J u``. Linearising ``phi``
at ``Delta`` (the paper drops the higher-order ``u`` terms, eq. 13) gives
``phi_{k+1}(u) ~ phi(Delta) + g . u`` with ``g = grad phi(Delta)^T B(tau) J``.
"""

from __future__ import annotations

import numpy as np

_TINY_M = 1e-9


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def index_terms(
    dp: np.ndarray, dv: np.ndarray, da: np.ndarray, r_sum: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface distance ``d``, ``d'`` and ``d''`` of pairs: ``(K,)`` each (eq. 12)."""
    D = np.maximum(np.linalg.norm(dp, axis=-1), _TINY_M)
    d_dot = _dot(dp, dv) / D
    d_ddot = (_dot(dv, dv) + _dot(dp, da)) / D - d_dot * d_dot / D
    return D - r_sum, d_dot, d_ddot


def safety_index(
    d: np.ndarray, d_dot: np.ndarray, d_ddot: np.ndarray, d_min: float, lam1: float, lam2: float
) -> np.ndarray:
    """``phi = d_min^2 - d|d| - lambda_1 d' - lambda_2 d''`` (eq. 6), ``(K,)``."""
    return d_min * d_min - d * np.abs(d) - lam1 * d_dot - lam2 * d_ddot


def index_gradient(
    dp: np.ndarray,
    dv: np.ndarray,
    da: np.ndarray,
    r_sum: np.ndarray,
    lam1: float,
    lam2: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gradient of ``phi`` w.r.t. the relative state: ``(d (K,), dphi/ddp, dphi/ddv, dphi/dda)``
    (three ``(K, 3)`` arrays)."""
    D = np.maximum(np.linalg.norm(dp, axis=-1), _TINY_M)[:, None]
    n = dp / D
    d = D[:, 0] - r_sum
    d_dot = _dot(n, dv)[:, None]
    N = (_dot(dv, dv) + _dot(dp, da))[:, None]
    dd_dp = (dv - d_dot * n) / D  # d(d')/d(dp)
    ddd_dp = da / D - N * n / (D * D) - 2.0 * d_dot * dd_dp / D + d_dot * d_dot * n / (D * D)
    g_p = -2.0 * np.abs(d)[:, None] * n - lam1 * dd_dp - lam2 * ddd_dp
    g_v = -lam1 * n - lam2 * (2.0 * dv - 2.0 * d_dot * n) / D
    g_a = -lam2 * n
    return d, g_p, g_v, g_a


def predict_delta(
    p_r: np.ndarray,
    v_r: np.ndarray,
    a_r: np.ndarray,
    c_r: np.ndarray,
    p_o: np.ndarray,
    v_o: np.ndarray,
    tau: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``Delta`` of eq. 11 (``delta_{k+1}`` at ``u = 0``): ``(dp, dv, da)`` each ``(K, 3)``.

    Robot point ``(p_r, v_r, a_r)`` with drift jerk ``c_r``; other point ``(p_o, v_o)`` moving
    at constant velocity (its acceleration is zero, eq. 4)."""
    t2, t3 = tau * tau / 2.0, tau**3 / 6.0
    dp = p_r + tau * v_r + t2 * a_r + t3 * c_r - (p_o + tau * v_o)
    dv = v_r + tau * a_r + t2 * c_r - v_o
    da = a_r + tau * c_r
    return dp, dv, da


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
) -> tuple[np.ndarray, np.ndarray]:
    """Linearised ``phi_{k+1}(u) ~ phi0 + g . u`` (eq. 13): ``phi0 (K,)`` and ``g (K, n)``.

    ``J_r (K, 3, n)`` is the robot point's Jacobian."""
    dp, dv, da = predict_delta(p_r, v_r, a_r, c_r, p_o, v_o, tau)
    d, g_p, g_v, g_a = index_gradient(dp, dv, da, r_sum, lam1, lam2)
    d_, d_dot, d_ddot = index_terms(dp, dv, da, r_sum)
    phi0 = safety_index(d_, d_dot, d_ddot, d_min, lam1, lam2)
    w = (tau**3 / 6.0) * g_p + (tau * tau / 2.0) * g_v + tau * g_a  # (K, 3)
    g = np.einsum("ki,kin->kn", w, J_r)
    return phi0, g
