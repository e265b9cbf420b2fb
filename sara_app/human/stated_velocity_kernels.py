"""A skeleton's stated velocities reconciled with the estimate from its positions, compiled
(:mod:`sara_app.human.stated_velocity` states the rule and why the ball encloses the lens;
``tests/stated_velocity_reference.py`` is the plain numpy oracle)."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from sara_app.kernel_types import RO1, RO2, W1, W2, WB1


@njit(types.void(RO2, RO1, RO2, RO1, W2, W1, WB1, W1), cache=True)
def reconcile_step(
    v_s: np.ndarray,
    dv_s: np.ndarray,
    v_e: np.ndarray,
    dv_e: np.ndarray,
    v: np.ndarray,
    dv: np.ndarray,
    contradicted: np.ndarray,
    gap: np.ndarray,
) -> None:
    """Per joint of ``v_s``, ``v_e (J, 3)``, ``dv_s``, ``dv_e (J,)``: the ball to use ``v (J, 3)``,
    ``dv (J,)`` (the smallest of the stated ball, the estimate's and the lens's circle ball;
    the estimate's where the two do not meet), ``contradicted (J,)`` and ``gap (J,)``
    ``|v_e - v_s|`` (NaN where a bound is infinite)."""
    for j in range(dv_s.shape[0]):
        rs, re = dv_s[j], dv_e[j]
        both = math.isfinite(rs) and math.isfinite(re)
        d = math.nan
        if both:
            d = math.sqrt((v_e[j, 0] - v_s[j, 0]) ** 2 + (v_e[j, 1] - v_s[j, 1]) ** 2
                          + (v_e[j, 2] - v_s[j, 2]) ** 2)  # fmt: skip
        gap[j] = d
        contradicted[j] = both and d > rs + re
        stated = math.isfinite(rs) and not contradicted[j] and not re < rs
        for c in range(3):
            v[j, c] = v_s[j, c] if stated else v_e[j, c]
        dv[j] = rs if stated else re
        if both and not contradicted[j] and d > 0.0:
            a = (d * d + rs * rs - re * re) / (2.0 * d)
            h = math.sqrt(max(rs * rs - a * a, 0.0))
            if a >= 0.0 and a <= d and h < dv[j]:
                for c in range(3):
                    v[j, c] = v_s[j, c] + a * ((v_e[j, c] - v_s[j, c]) / d)
                dv[j] = h
