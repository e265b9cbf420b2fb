"""The streaming velocity estimate's per-frame step, compiled (:mod:`sara_app.human.velocity`
states the estimate and its error bound; ``tests/velocity_reference.py`` is the plain numpy
oracle). With the numpy version ``VelocityEstimator.update`` cost 14.5 us per frame (a dozen
small array operations), with this one 1.8 us (a warm loop, 2026-11-28).
"""

from __future__ import annotations

import numpy as np
from numba import njit, types

from sara_app.kernel_types import F8, I8, RO1, RO2, ROB1, W1, W2, W3, WB2


@njit(types.int64(W1, W3, WB2, I8, F8, RO2, ROB1, F8, RO1, W2, W1), cache=True)
def velocity_step(
    times: np.ndarray,
    frames: np.ndarray,
    trusted_ring: np.ndarray,
    count: int,
    t_s: float,
    y: np.ndarray,
    trusted: np.ndarray,
    delta_y_m: float,
    a_max_mps2: np.ndarray,
    v: np.ndarray,
    dv: np.ndarray,
) -> int:
    """Shift the frame ``(t_s, y (J, 3), trusted (J,))`` into the rings ``times (N,)``,
    ``frames (N, J, 3)``, ``trusted_ring (N, J)`` (newest first) holding ``count`` frames, and
    write each joint's backward difference over its best lag ``v (J, 3)`` and its error bound
    ``dv (J,)`` (infinite, and ``v`` zero, without a past or when either frame is distrusted).
    Returns the new count."""
    N, J = frames.shape[0], frames.shape[1]
    for n in range(N - 1, 0, -1):
        times[n] = times[n - 1]
        for j in range(J):
            trusted_ring[n, j] = trusted_ring[n - 1, j]
            for c in range(3):
                frames[n, j, c] = frames[n - 1, j, c]
    times[0] = t_s
    for j in range(J):
        trusted_ring[0, j] = trusted[j]
        for c in range(3):
            frames[0, j, c] = y[j, c]
    count = min(count + 1, N)
    lags = count - 1
    for j in range(J):
        best, bound = -1, np.inf
        for lag in range(1, lags + 1):  # the first lag of the smallest bound
            dt = t_s - times[lag]
            b = 2.0 * delta_y_m / dt + 0.5 * a_max_mps2[j] * dt
            if best < 0 or b < bound:
                best, bound = lag, b
        if best < 0 or not (trusted_ring[0, j] and trusted_ring[best, j]):
            dv[j] = np.inf
        else:
            dv[j] = bound
        if best < 0 or not np.isfinite(dv[j]):
            for c in range(3):
                v[j, c] = 0.0
        else:
            dt = t_s - times[best]
            for c in range(3):
                v[j, c] = (y[j, c] - frames[best, j, c]) / dt
    return count
