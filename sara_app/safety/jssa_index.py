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
``H = F_xx``). So ``d''`` loses ``slide / |dp|`` (``slide >= 0``; compiled:
``jssa_kernels.sliding_terms``): without it a robot moving along a person's limb (or the limb along
the link) counts as "flying past" (``|dv|^2 / |dp|`` in ``d''``) and the index lets it close in
while the true distance shrinks. ``d'`` needs no correction (first order, envelope theorem).
``slide`` is taken at the current state and held over the cycle (its dependence on ``u`` is
O(tau^2), as the terms the paper's linearisation drops).

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


def index_terms(
    dp: np.ndarray,
    dv: np.ndarray,
    da: np.ndarray,
    r_sum: np.ndarray,
    slide: np.ndarray | float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Surface distance ``d``, ``d'`` and ``d''`` of pairs: ``(K,)`` each (eq. 12, minus the
    sliding correction ``slide`` (K,) of the module notes; 0: material points)."""
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
