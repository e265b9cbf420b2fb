"""The conformance monitor's per-frame computation in plain numpy: the oracle of
``sara_app.human.conformance_kernels.observe_frame`` (the library's code before it was
compiled)."""

from __future__ import annotations

import numpy as np


def observe_frame_reference(
    t_ring: np.ndarray, y_ring: np.ndarray, ok_ring: np.ndarray, t_s: float, y: np.ndarray,
    trusted: np.ndarray, delta_y_m: float, jump_speed_mps: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """Shifts the frame into the rings (in place) and returns ``(speed (J,), acc (J,),
    rise (J,))`` (rise: the upward speed, z up)."""
    for arr, new in ((t_ring, t_s), (y_ring, y), (ok_ring, trusted)):
        arr[1:] = arr[:-1]
        arr[0] = new
    speed = np.array(jump_speed_mps, dtype=float)
    acc = np.zeros(y.shape[0])
    rise = np.zeros(y.shape[0])
    k = 1
    while k < len(t_ring) and np.isfinite(t_ring[k]):
        dt = t_s - t_ring[k]
        ok = ok_ring[0] & ok_ring[k]
        d = np.linalg.norm(y - y_ring[k], axis=1) - 2.0 * delta_y_m
        speed = np.maximum(speed, np.where(ok, d / dt, 0.0))
        up = y[:, 2] - y_ring[k][:, 2] - 2.0 * delta_y_m
        rise = np.maximum(rise, np.where(ok, up / dt, 0.0))
        if k >= 2:
            h = k // 2
            t1 = t_ring[h]
            w = (t1 - t_ring[k]) / dt
            chord = y_ring[k] + w * (y - y_ring[k])
            dev = np.linalg.norm(y_ring[h] - chord, axis=1) - 2.0 * delta_y_m
            span2 = (t1 - t_ring[k]) * (t_s - t1)
            acc = np.maximum(acc, np.where(ok & ok_ring[h], 2.0 * dev / span2, 0.0))
        k *= 2
    return speed, acc, rise
