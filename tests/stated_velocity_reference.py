"""The plain numpy version of ``sara_app.human.stated_velocity.reconcile``: the oracle of its
compiled step."""

from __future__ import annotations

import numpy as np


def reconcile(
    v_s: np.ndarray, dv_s: np.ndarray, v_e: np.ndarray, dv_e: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The velocity ``(J, 3)`` m/s and its bound ``(J,)`` to use, from the stated ``v_s (J, 3)``,
    ``dv_s (J,)`` and the estimate ``v_e (J, 3)``, ``dv_e (J,)`` (``inf``: none); plus per joint
    whether the two contradict ``(J,)`` and their gap ``|v_s - v_e|`` ``(J,)`` (m/s; NaN where
    a bound is infinite)."""
    finite = np.isfinite(dv_s) & np.isfinite(dv_e)
    diff = v_e - v_s
    d = np.where(finite, np.linalg.norm(diff, axis=1), np.nan)
    with np.errstate(invalid="ignore"):
        contradicted = finite & (d > dv_s + dv_e)
    # the smaller of the two balls (the estimate where the stated one is unknown or refused)
    stated_smaller = np.isfinite(dv_s) & ~contradicted & ~(dv_e < dv_s)
    v = np.where(stated_smaller[:, None], v_s, v_e)
    dv = np.where(stated_smaller, dv_s, dv_e)
    lens = finite & ~contradicted & (d > 0)
    if lens.any():
        dl, rs, re = d[lens], dv_s[lens], dv_e[lens]
        a = (dl * dl + rs * rs - re * re) / (2.0 * dl)
        h = np.sqrt(np.maximum(rs * rs - a * a, 0.0))
        better = (a >= 0.0) & (a <= dl) & (h < dv[lens])
        idx = np.flatnonzero(lens)[better]
        u = diff[idx] / dl[better, None]
        v[idx] = v_s[idx] + a[better, None] * u
        dv[idx] = h[better]
    return v, dv, contradicted, d
