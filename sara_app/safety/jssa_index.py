"""JSSA safety index (Liu et al. 2022 eq. 6, 12) and its linearised constraint (eq. 9-13).

All functions are batched over critical pairs ``K``. A pair's relative state is
``delta = [dp; dv; da]`` (robot point minus human/obstacle point, each ``(K, 3)``, world frame)
between the two capsule AXIS points; the surface distance is ``d = |dp| - r_sum`` with
``r_sum (K,)`` the two radii, so ``d', d''`` are those of ``|dp|``:

- ``d'  = n . dv`` with ``n = dp / |dp|``
- ``d'' = (|dv|^2 + dp . da) / |dp| - d'^2 / |dp|``                      (eq. 12)
- ``phi = d_min^2 - d |d| - lambda_1 d' - lambda_2 d''``                    (eq. 6)

``d |d|`` replaces the paper's ``d^2`` so that ``phi`` keeps growing with penetration depth
(``d < 0``); both define the same set ``d >= d_min`` (``d_min > 0``).

Sliding closest points (not in the paper). Eq. 12 differentiates the distance between two
MATERIAL points. For capsules the closest points slide along the axes, and the second derivative
of the true (minimum) distance is smaller: with ``F = |w|^2 / 2`` over the axis parameters
``x = (s, t)``, ``F*'' = F_tt - F_tx H^-1 F_xt`` over the interior parameters (envelope theorem;
``H = F_xx``). So ``d''`` loses ``slide / |dp|`` (:func:`sliding_correction`, ``slide >= 0``):
without it a robot moving along a person's limb (or the limb along the link) counts as "flying
past" (``|dv|^2 / |dp|`` in ``d''``) and the index lets it close in while the true distance
shrinks. ``d'`` needs no correction (first order, envelope theorem). ``slide`` is taken at the
current state and held over the cycle (its dependence on ``u`` is O(tau^2), as the terms the
paper's linearisation drops).

Discrete prediction (eq. 8-11): with the jerk-controlled robot point
``M_{k+1} = A(tau) M_k + B(tau) (J u + c)`` and the other point under the constant-velocity
model (eq. 4; static obstacles: eq. 2), ``delta_{k+1} = Delta + B(tau) J u``. Linearising ``phi``
at ``Delta`` (the paper drops the higher-order ``u`` terms, eq. 13) gives
``phi_{k+1}(u) ~ phi(Delta) + g . u`` with ``g = grad phi(Delta)^T B(tau) J``.
"""

from __future__ import annotations

import numpy as np

_TINY_M = 1e-9
_INTERIOR = 1e-9  # closest-point parameters farther than this from 0 and 1 slide


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


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


def index_terms(
    dp: np.ndarray,
    dv: np.ndarray,
    da: np.ndarray,
    r_sum: np.ndarray,
    slide: np.ndarray | float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface distance ``d``, ``d'`` and ``d''`` of pairs: ``(K,)`` each (eq. 12, minus the
    sliding correction ``slide`` (K,) of :func:`sliding_correction`; 0: material points)."""
    D = np.maximum(np.linalg.norm(dp, axis=-1), _TINY_M)
    d_dot = _dot(dp, dv) / D
    d_ddot = (_dot(dv, dv) + _dot(dp, da) - slide) / D - d_dot * d_dot / D
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
    slide: np.ndarray | float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Gradient of ``phi`` w.r.t. the relative state: ``(d (K,), dphi/ddp, dphi/ddv, dphi/dda)``
    (three ``(K, 3)`` arrays); ``slide`` is held constant."""
    D = np.maximum(np.linalg.norm(dp, axis=-1), _TINY_M)[:, None]
    n = dp / D
    d = D[:, 0] - r_sum
    d_dot = _dot(n, dv)[:, None]
    N = (_dot(dv, dv) + _dot(dp, da) - slide)[:, None]
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
