"""The conformance monitor's per-frame computation, compiled (:mod:`sara_app.human.conformance`
states the conditions; ``tests/conformance_reference.py`` is the plain numpy oracle).

One call per frame and person: the frame enters the monitor's rings (newest first) and, per
joint, the least speed, upward speed and acceleration that explain the trusted positions over
spans of 1, 2, 4, ... frames back come out. The numpy version cost about 130 us per frame
(dozens of small array operations on ``(J, 3)`` arrays); this one a few microseconds.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from sara_app.kernel_types import F8, RO1, RO2, ROB1, W1, W3, WB2


@njit(types.void(W1, W3, WB2, F8, RO2, ROB1, F8, RO1, W1, W1, W1), cache=True)
def observe_frame(
    t_ring: np.ndarray,
    y_ring: np.ndarray,
    ok_ring: np.ndarray,
    t_s: float,
    y: np.ndarray,
    trusted: np.ndarray,
    delta_y_m: float,
    jump_speed_mps: np.ndarray,
    speed_mps: np.ndarray,
    acc_mps2: np.ndarray,
    rise_mps: np.ndarray,
) -> None:
    """Shift the frame ``(t_s, y (J, 3), trusted (J,))`` into the rings ``t_ring (N,)``,
    ``y_ring (N, J, 3)``, ``ok_ring (N, J)`` (newest first) and write per joint the speed
    ``speed_mps (J,)`` (at least ``jump_speed_mps (J,)``, the gate's speed of a joint that only
    jumped) and acceleration ``acc_mps2 (J,)`` the trusted positions need over spans of
    ``k = 1, 2, 4, ...`` frames back (``k < N``), beyond ``2 delta_y`` of noise, and the
    vertical speed upwards ``rise_mps (J,)`` they need over the same spans (``z`` up)."""
    N, J = y_ring.shape[0], y_ring.shape[1]
    for n in range(N - 1, 0, -1):
        t_ring[n] = t_ring[n - 1]
        for j in range(J):
            ok_ring[n, j] = ok_ring[n - 1, j]
            for c in range(3):
                y_ring[n, j, c] = y_ring[n - 1, j, c]
    t_ring[0] = t_s
    for j in range(J):
        ok_ring[0, j] = trusted[j]
        for c in range(3):
            y_ring[0, j, c] = y[j, c]
        speed_mps[j] = jump_speed_mps[j]
        acc_mps2[j] = 0.0
        rise_mps[j] = 0.0
    noise = 2.0 * delta_y_m
    k = 1
    while k < N and math.isfinite(t_ring[k]):
        dt = t_s - t_ring[k]
        h = k // 2
        for j in range(J):
            ok = ok_ring[0, j] and ok_ring[k, j]
            d = 0.0
            for c in range(3):
                d += (y[j, c] - y_ring[k, j, c]) ** 2
            v = (math.sqrt(d) - noise) / dt if ok else 0.0
            if v > speed_mps[j]:
                speed_mps[j] = v
            up = (y[j, 2] - y_ring[k, j, 2] - noise) / dt if ok else 0.0
            if up > rise_mps[j]:
                rise_mps[j] = up
            if k >= 2:
                t1 = t_ring[h]
                w = (t1 - t_ring[k]) / dt
                dev = 0.0
                for c in range(3):
                    chord = y_ring[k, j, c] + w * (y[j, c] - y_ring[k, j, c])
                    dev += (y_ring[h, j, c] - chord) ** 2
                span2 = (t1 - t_ring[k]) * (t_s - t1)
                a = 2.0 * (math.sqrt(dev) - noise) / span2 if ok and ok_ring[h, j] else 0.0
                if a > acc_mps2[j]:
                    acc_mps2[j] = a
        k *= 2
