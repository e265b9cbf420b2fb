"""Compiled (numba) kernels of the reachability models in :mod:`sara_app.human.reach`.

One kernel per model writes the capsules into the caller's buffers. The formulas, their
soundness conditions and the shapes are documented on the :class:`~sara_app.human.reach.
HumanReach` methods; ``tests/test_reach_kernels.py`` checks every kernel against a plain numpy
transcription of the same formulas. At the size of one human (15 joints, 14 parts) a model is a
few dozen numpy operations of about 1-3 us each, and the same loop compiled costs about 1 us.

Every kernel has an explicit signature (read-only ``'A'``-layout inputs, writable outputs) and
``cache=True``: compiled or loaded from the cache when this module is imported, never on a first
call in a control loop.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

from sara_app.kernel_types import F8 as _f8
from sara_app.kernel_types import I8 as _i8
from sara_app.kernel_types import RO1 as _RO1
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import RO3 as _RO3
from sara_app.kernel_types import ROI1 as _ROI1
from sara_app.kernel_types import ROI2 as _ROI2
from sara_app.kernel_types import W2 as _W2
from sara_app.kernel_types import W3 as _W3
from sara_app.kernel_types import W4 as _W4
from sara_app.kernel_types import W5 as _W5

__all__ = [
    "KIND_ACC",
    "KIND_ISO",
    "KIND_POS",
    "KIND_VEL",
    "acc_sets",
    "person_sets",
    "pos_sets",
    "static_sets",
]

KIND_ACC, KIND_VEL, KIND_ISO, KIND_POS = 0, 1, 2, 3
"""Model codes of the compiled checks (``vel`` and ``iso13855`` are rows 0 and 1 of the static
sets' constants)."""


@njit(types.void(_RO3, _ROI2, _RO1, _f8, _RO1, _RO1, _W4, _W2), cache=True)
def static_sets(
    y: np.ndarray,
    part_joints: np.ndarray,
    t_end_s: np.ndarray,
    delay_s: float,
    base_m: np.ndarray,
    speed_mps: np.ndarray,
    ends: np.ndarray,
    radius: np.ndarray,
) -> None:
    """Capsules at the measured pose ``ends (H, P, 2, 3) = y[:, part_joints]`` with radius
    ``(K, P) = base + speed * (t_end + delay)`` (R_VEL, ISO 13855)."""
    for h in range(y.shape[0]):
        for p in range(part_joints.shape[0]):
            for e in range(2):
                for r in range(3):
                    ends[h, p, e, r] = y[h, part_joints[p, e], r]
    for k in range(t_end_s.shape[0]):
        tau = t_end_s[k] + delay_s
        for p in range(base_m.shape[0]):
            radius[k, p] = tau * speed_mps[p] + base_m[p]


@njit(
    types.void(_RO3, _ROI1, _ROI1, _ROI1, _ROI2, _RO1, _f8, _RO1, _RO1, _i8, _W4, _W3),
    cache=True,
)
def pos_sets(
    y: np.ndarray,
    seg_a: np.ndarray,
    seg_b: np.ndarray,
    seg_limb: np.ndarray,
    cap_joints: np.ndarray,
    t_end_s: np.ndarray,
    delay_s: float,
    speed_mps: np.ndarray,
    base_m: np.ndarray,
    n_limbs: int,
    ends: np.ndarray,
    radius: np.ndarray,
) -> None:
    """R_POS: ``ends (H, C, 2, 3) = y[:, cap_joints]``; radius ``(H, K, C) = speed * tau +
    base``, plus for the first ``n_limbs`` capsules the summed measured lengths of the limb's
    segments ``y[seg_b] - y[seg_a]`` (segment ``i`` belongs to limb ``seg_limb[i]``)."""
    H, C, K = y.shape[0], cap_joints.shape[0], t_end_s.shape[0]
    lengths = np.zeros(n_limbs)
    for h in range(H):
        for c in range(n_limbs):
            lengths[c] = 0.0
        for i in range(seg_a.shape[0]):
            dx = y[h, seg_b[i], 0] - y[h, seg_a[i], 0]
            dy = y[h, seg_b[i], 1] - y[h, seg_a[i], 1]
            dz = y[h, seg_b[i], 2] - y[h, seg_a[i], 2]
            lengths[seg_limb[i]] += math.sqrt(dx * dx + dy * dy + dz * dz)
        for c in range(C):
            for e in range(2):
                for r in range(3):
                    ends[h, c, e, r] = y[h, cap_joints[c, e], r]
        for k in range(K):
            tau = t_end_s[k] + delay_s
            for c in range(C):
                radius[h, k, c] = tau * speed_mps[c] + base_m[c]
                if c < n_limbs:
                    radius[h, k, c] += lengths[c]


@njit(
    types.void(_RO3, _RO3, _RO2, _RO1, _RO1, _f8, _RO1, _f8, _RO1, _ROI1, _ROI1, _ROI2, _W5, _W3),
    cache=True,
)
def acc_sets(
    y: np.ndarray,
    v: np.ndarray,
    dv: np.ndarray,
    t_start_s: np.ndarray,
    t_end_s: np.ndarray,
    delay_s: float,
    a_half: np.ndarray,
    delta_y_m: float,
    half_thickness_m: np.ndarray,
    ia: np.ndarray,
    ib: np.ndarray,
    end_index: np.ndarray,
    ends: np.ndarray,
    radius: np.ndarray,
) -> None:
    """R_ACC (see :meth:`HumanReach.acc`). Per human and interval, with ``tau_a, tau_b`` the
    interval plus the delay: joint radii ``X = [R(tau_b) | R(tau_b) + |v| (tau_b - tau_a) / 2]``
    with ``R = dv tau_b + a_max tau_b^2 / 2 + delta_y`` (``a_half = a_max / 2``); part radius
    ``max(X[ia], X[ib]) + half thickness``; ends ``y + v tau`` at ``tau_a`` / mid / ``tau_b``,
    picked by ``end_index (P, 2)`` in ``[0, 3J)`` (``time * J + joint``). Outputs ``ends (H, K,
    P, 2, 3)``, ``radius (H, K, P)``."""
    H, J, K, P = y.shape[0], y.shape[1], t_end_s.shape[0], ia.shape[0]
    X = np.empty(2 * J)
    times = np.empty(3)
    for h in range(H):
        for k in range(K):
            ta = t_start_s[k] + delay_s
            tb = t_end_s[k] + delay_s
            times[0], times[1], times[2] = ta, 0.5 * (ta + tb), tb
            half_dt = 0.5 * (tb - ta)
            for j in range(J):
                R = dv[h, j] * tb + (a_half[j] * (tb * tb) + delta_y_m)
                vx, vy, vz = v[h, j, 0], v[h, j, 1], v[h, j, 2]
                speed = math.sqrt(vx * vx + vy * vy + vz * vz)
                X[j] = R
                X[J + j] = speed * half_dt + R
            for p in range(P):
                xa, xb = X[ia[p]], X[ib[p]]
                big = xa if xa >= xb else (xb if xb >= xa else math.nan)  # NaN stays NaN
                radius[h, k, p] = big + half_thickness_m[p]
                for e in range(2):
                    x = end_index[p, e]
                    t, j = x // J, x % J
                    for r in range(3):
                        ends[h, k, p, e, r] = y[h, j, r] + v[h, j, r] * times[t]


STATIC = types.Tuple((_ROI2, _RO2, _RO2))
"""``(part_joints (P, 2), base_m (2, P), speed_mps (2, P))``: rows vel, iso13855."""
ACC = types.Tuple((_RO1, _RO1, _ROI1, _ROI1, _ROI2))
"""``(a_half (J,), half_thickness_m (P,), ia, ib (P,), end_index (P, 2))``."""
POS = types.Tuple((_ROI1, _ROI1, _ROI1, _ROI2, _RO1, _RO1))
"""``(seg_a, seg_b, seg_limb, cap_joints (C, 2), speed_mps (C,), base_m (C,))``."""


@njit(cache=True)
def person_sets(
    kind: int,
    h: int,
    human: Any,
    age_s: float,
    times: np.ndarray,
    lo: int,
    hi: int,
    constants: Any,
    buffers: Any,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Person ``h``'s capsules of model ``kind`` (``KIND_*``) over intervals ``lo:hi`` of the
    sample times ``times (K+1,)`` (from now), grown from the measurement ``age_s`` ago: ``(ends
    (ke, C, 2, 3), radius (k, C), ke)`` views of ``buffers``, ``ke = k`` for ACC, else 1 (the
    same axes on every interval). ``human = (y, v (H, J, 3), dv (H, J), ...)``; ``constants =
    (static, acc, pos, (delay_s, delta_y_m), n_limbs)`` (:data:`STATIC`, :data:`ACC`,
    :data:`POS`; :meth:`HumanReach.kernel_constants <sara_app.human.reach.HumanReach>`);
    ``buffers = (t_start, t_end (K,), acc ends (1, K, P, 2, 3), acc radius (1, K, P), static
    ends (1, P, 2, 3), static radius (K, P), pos ends (1, C, 2, 3), pos radius (1, K, C))``.
    The same kernels as :meth:`HumanReach.acc <sara_app.human.reach.HumanReach>`, ``vel``,
    ``iso13855`` and ``pos``."""
    y, v, dv = human[0], human[1], human[2]
    static, acc, pos, delays, n_limbs = constants
    delay_s, delta_y_m = delays
    t_start, t_end, acc_e, acc_r, st_e, st_r, pos_e, pos_r = buffers
    k = hi - lo
    for x in range(k):
        t_start[x] = times[lo + x] + age_s
        t_end[x] = times[lo + 1 + x] + age_s
    ts, te = t_start[:k], t_end[:k]
    yh = y[h : h + 1]
    if kind == KIND_ACC:
        a_half, half_thickness, ia, ib, end_index = acc
        acc_sets(yh, v[h : h + 1], dv[h : h + 1], ts, te, delay_s, a_half, delta_y_m,
                 half_thickness, ia, ib, end_index, acc_e[:, :k], acc_r[:, :k])  # fmt: skip
        return acc_e[0, :k], acc_r[0, :k], k
    if kind == KIND_POS:
        pos_sets(yh, pos[0], pos[1], pos[2], pos[3], te, delay_s, pos[4], pos[5], n_limbs,
                 pos_e, pos_r[:, :k])  # fmt: skip
        return pos_e[0:1], pos_r[0, :k], 1
    row = 0 if kind == KIND_VEL else 1
    part_joints, base, speed = static
    static_sets(yh, part_joints, te, delay_s, base[row], speed[row], st_e, st_r[:k])
    return st_e[0:1], st_r[:k], 1
