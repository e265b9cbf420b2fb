"""The JSSA projection (Liu et al. 2022 eq. 14) and the fallback brake.

``min_u sum_i w_i (u_i - u0_i)^2  s.t.  G u <= b,  lo <= u <= hi``  (``w > 0``: diagonal ``V``).

One constraint (compiled: :func:`sara_app.safety.jssa_kernels.project_halfspace_box`; reference in
``tests/jssa_reference.py``), solved exactly. The problem is a separable convex
quadratic with one linear constraint over a box. Its Lagrangian with multiplier ``mu >= 0`` for
``g . u <= b`` separates per coordinate, and for fixed ``mu`` the box-constrained minimiser is
``u(mu) = clip(u0 - mu g / w, lo, hi)``. ``f(mu) = g . u(mu)`` is continuous, piecewise linear and
non-increasing, so the KKT conditions (``mu = 0`` and ``f(0) <= b``, or ``mu > 0`` and
``f(mu) = b``) are met by the root of a monotone piecewise-linear function: sort its at most
``2n`` breakpoints and interpolate on the piece where it crosses ``b``. This is exact up to
round-off, O(n log n), has no iterations or tolerances to tune, and reports infeasibility exactly
(``min_box g . u > b``). A general QP solver would add ~50-100 us of Python overhead per cycle for
no gain in this case.

Several constraints (:func:`project_polytope_box`): a maintained QP solver through qpsolvers
(DAQP, a dual active-set method that is exact for small dense QPs), with the result checked
against the constraints.

Fallback (:func:`brake_jerk`): ``u = clip(-2 w q'' - w^2 q', lo, hi)``, a critically damped
law on ``(q', q'')`` whose saturation keeps the sign of the unsaturated law, bringing the joints
to rest within the jerk bounds.
"""

from __future__ import annotations

import numpy as np

FEAS_TOL = 1e-9
"""Slack accepted on ``G u <= b`` (relative to the scale of ``b``) before a QP is infeasible."""


def project_polytope_box(
    u0: np.ndarray,
    w: np.ndarray,
    G: np.ndarray,
    b: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
) -> tuple[np.ndarray, bool]:
    """Projection with ``K`` constraints ``G (K, n) u <= b (K,)`` via qpsolvers/DAQP:
    ``(u (n,), feasible)``. Returns the box-clipped nominal when ``K == 0``."""
    u_box = np.clip(u0, lo, hi)
    if G.shape[0] == 0 or np.all(G @ u_box <= b):
        return u_box, True
    from qpsolvers import solve_qp

    try:
        u = solve_qp(np.diag(w), -w * u0, G, b, lb=lo, ub=hi, solver="daqp")
    except Exception:  # a solver failure is an infeasible cycle, never an exception
        u = None
    if u is None or not np.all(np.isfinite(u)):
        return np.where(G.sum(axis=0) > 0.0, lo, hi), False
    u = np.clip(u, lo, hi)
    tol = FEAS_TOL * np.maximum(1.0, np.abs(b)) + 1e-7 * np.abs(G).sum(axis=1)
    return u, bool(np.all(G @ u <= b + tol))


def brake_jerk(
    q_dot: np.ndarray, q_ddot: np.ndarray, lo: np.ndarray, hi: np.ndarray, omega: float
) -> np.ndarray:
    """Fallback jerk ``(n,)``: critically damped braking of ``(q', q'')`` within ``[lo, hi]``."""
    u = -2.0 * omega * q_ddot - omega * omega * q_dot
    return np.clip(np.nan_to_num(u, nan=0.0, posinf=0.0, neginf=0.0), lo, hi)
