"""The conformance monitor's per-frame computation, compiled (:mod:`sara_app.human.conformance`
states the conditions; ``tests/conformance_reference.py`` is the plain numpy oracle).

One call per frame and person: the frame enters the monitor's rings (newest first) and, per
joint, the least speed, upward speed and acceleration that explain the trusted positions over
spans of 1, 2, 4, ... frames back come out. The numpy version cost about 130 us per frame
(dozens of small array operations on ``(J, 3)`` arrays); this one a few microseconds. Where the
parameter set bounds displacements (R_VEL's table), a second call measures each joint's distance
to where it was up to the table's horizon back (:func:`observe_displacement`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

from sara_app.human import reach_kernels
from sara_app.human.reach_kernels import displacement_bound
from sara_app.kernel_types import F8, I8, RO1, RO2, ROB1, W1, W3, WB2, source_digest


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


def _make_displacement_kernel() -> Any:
    """Build :func:`observe_displacement` with its callee's source digest in the closure."""
    sources = source_digest(reach_kernels)

    @njit(types.void(W1, W3, WB2, I8, F8, RO2, ROB1, F8, RO2, F8, RO1, W1, W1), cache=True)
    def observe_displacement(
        t_ring: np.ndarray,
        y_ring: np.ndarray,
        ok_ring: np.ndarray,
        slot: int,
        t_s: float,
        y: np.ndarray,
        trusted: np.ndarray,
        delta_y_m: float,
        disp_m: np.ndarray,
        disp_step_s: float,
        v_max_mps: np.ndarray,
        value_m: np.ndarray,
        bound_m: np.ndarray,
    ) -> None:
        """Per joint, the distance beyond ``2 delta_y`` between the trusted position ``y (J, 3)``
        at ``t_s`` and each trusted one in the circular rings ``t_ring (M,)``, ``y_ring (M, J,
        3)``, ``ok_ring (M, J)`` up to the table's horizon back (``disp_m (J, N)`` cells of
        ``disp_step_s``), against the displacement bound there
        (:func:`~sara_app.human.reach_kernels.displacement_bound`): the pair that exceeds its
        bound most, or else the one nearest it, goes to ``value_m``, ``bound_m (J,)``. Then the
        frame is written into ring slot ``slot``."""
        M, J = y_ring.shape[0], y_ring.shape[1]
        horizon = disp_m.shape[1] * disp_step_s
        noise = 2.0 * delta_y_m
        for j in range(J):
            value_m[j] = 0.0
            bound_m[j] = math.inf
        for m in range(M):
            tau = t_s - t_ring[m]
            if not (tau > 0.0 and tau <= horizon + 1e-9 and len(sources) > 0):
                continue
            for j in range(J):
                if not (trusted[j] and ok_ring[m, j]):
                    continue
                d = 0.0
                for c in range(3):
                    d += (y[j, c] - y_ring[m, j, c]) ** 2
                d = math.sqrt(d) - noise
                b = displacement_bound(tau, v_max_mps[j], disp_m, j, disp_step_s)
                if d - b > value_m[j] - bound_m[j]:
                    value_m[j], bound_m[j] = d, b
        t_ring[slot] = t_s
        for j in range(J):
            ok_ring[slot, j] = trusted[j]
            for c in range(3):
                y_ring[slot, j, c] = y[j, c]

    return observe_displacement


observe_displacement = _make_displacement_kernel()
