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

from sara_app.kernel_types import B1 as _b1
from sara_app.kernel_types import F8 as _f8
from sara_app.kernel_types import I8 as _i8
from sara_app.kernel_types import RO1 as _RO1
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import RO3 as _RO3
from sara_app.kernel_types import ROI1 as _ROI1
from sara_app.kernel_types import ROI2 as _ROI2
from sara_app.kernel_types import W1 as _W1
from sara_app.kernel_types import W2 as _W2
from sara_app.kernel_types import W3 as _W3
from sara_app.kernel_types import W4 as _W4
from sara_app.kernel_types import W5 as _W5

__all__ = [
    "KIND_ACC",
    "KIND_COMBINED",
    "KIND_ISO",
    "KIND_POS",
    "KIND_VEL",
    "KINDS",
    "acc_sets",
    "combined_ball",
    "combined_sets",
    "people_sets",
    "person_sets",
    "pos_sets",
    "displacement_bound",
    "static_sets",
]

KIND_ACC, KIND_VEL, KIND_ISO, KIND_POS, KIND_COMBINED = 0, 1, 2, 3, 4
"""Model codes of the compiled checks (``vel`` and ``iso13855`` are rows 0 and 1 of the static
sets' constants)."""
KINDS = {"acc": KIND_ACC, "vel": KIND_VEL, "iso13855": KIND_ISO, "pos": KIND_POS,
         "combined": KIND_COMBINED}  # fmt: skip
"""The models :func:`person_sets` computes, by name (Pereira's arm model is numpy)."""


@njit(_f8(_f8, _f8, _RO2, _i8, _f8), cache=True)
def displacement_bound(
    tau: float, speed_mps: float, disp_m: np.ndarray, p: int, step_s: float
) -> float:
    """How far part ``p`` gets within ``tau`` (s): the smaller of ``speed tau`` and its
    displacement table ``disp_m (P, N)`` (cell ``i`` covers ``(i step, (i + 1) step]``; beyond
    the table its last value plus ``speed`` times the rest; ``N = 0``: no table)."""
    grown = tau * speed_mps
    n = disp_m.shape[1]
    if n == 0:
        return grown
    i = int(math.ceil(tau / step_s)) - 1  # rounding up picks the next (larger) cell: sound
    if i < 0:
        i = 0
    if i < n:
        d = disp_m[p, i]
    else:
        d = disp_m[p, n - 1] + speed_mps * (tau - n * step_s)
    return d if d < grown else grown


@njit(types.void(_RO3, _ROI2, _RO1, _f8, _RO1, _RO1, _RO2, _f8, _W4, _W2), cache=True)
def static_sets(
    y: np.ndarray,
    part_joints: np.ndarray,
    t_end_s: np.ndarray,
    delay_s: float,
    base_m: np.ndarray,
    speed_mps: np.ndarray,
    disp_m: np.ndarray,
    disp_step_s: float,
    ends: np.ndarray,
    radius: np.ndarray,
) -> None:
    """Capsules at the measured pose ``ends (H, P, 2, 3) = y[:, part_joints]`` with radius
    ``(K, P) = base + min(speed tau, disp(tau))``, ``tau = t_end + delay`` (R_VEL, ISO 13855;
    :func:`displacement_bound`, ``disp_m (P, N)``, ``N = 0``: ``speed tau``). Monotone in
    ``tau``, so the set at an interval's end covers the interval."""
    for h in range(y.shape[0]):
        for p in range(part_joints.shape[0]):
            for e in range(2):
                for r in range(3):
                    ends[h, p, e, r] = y[h, part_joints[p, e], r]
    for k in range(t_end_s.shape[0]):
        tau = t_end_s[k] + delay_s
        for p in range(base_m.shape[0]):
            radius[k, p] = base_m[p] + displacement_bound(tau, speed_mps[p], disp_m, p, disp_step_s)


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
    for h in range(H):
        for c in range(C):
            for e in range(2):
                for r in range(3):
                    ends[h, c, e, r] = y[h, cap_joints[c, e], r]
            length = 0.0  # no scratch array: the control cycle calls this per person
            if c < n_limbs:
                for i in range(seg_a.shape[0]):
                    if seg_limb[i] == c:
                        dx = y[h, seg_b[i], 0] - y[h, seg_a[i], 0]
                        dy = y[h, seg_b[i], 1] - y[h, seg_a[i], 1]
                        dz = y[h, seg_b[i], 2] - y[h, seg_a[i], 2]
                        length += math.sqrt(dx * dx + dy * dy + dz * dz)
            for k in range(K):
                radius[h, k, c] = (t_end_s[k] + delay_s) * speed_mps[c] + base_m[c]
                if c < n_limbs:
                    radius[h, k, c] += length


@njit(cache=True)
def _parts(
    X: np.ndarray,
    centre: np.ndarray,
    half_thickness_m: np.ndarray,
    ia: np.ndarray,
    ib: np.ndarray,
    end_index: np.ndarray,
    ends: np.ndarray,
    radius: np.ndarray,
) -> None:
    """Body-part capsules of one person and interval from the joints' radii ``X (2J,)`` (ball,
    two-joint) and centres ``centre (3, J, 3)`` at the interval's start, middle, end: radius
    ``max(X[ia], X[ib]) + half thickness``, ends picked by ``end_index (P, 2)`` in ``[0, 3J)``
    (``time * J + joint``); into ``ends (P, 2, 3)``, ``radius (P,)``."""
    J = centre.shape[1]
    for p in range(ia.shape[0]):
        xa, xb = X[ia[p]], X[ib[p]]
        big = xa if xa >= xb else (xb if xb >= xa else math.nan)  # NaN stays NaN
        radius[p] = big + half_thickness_m[p]
        for e in range(2):
            x = end_index[p, e]
            t, j = x // J, x % J
            for r in range(3):
                ends[p, e, r] = centre[t, j, r]


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
    H, J, K = y.shape[0], y.shape[1], t_end_s.shape[0]
    X = np.empty(2 * J)
    times = np.empty(3)
    centre = np.empty((3, J, 3))
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
            for t in range(3):
                for j in range(J):
                    for r in range(3):
                        centre[t, j, r] = y[h, j, r] + v[h, j, r] * times[t]
            _parts(X, centre, half_thickness_m, ia, ib, end_index, ends[h, k], radius[h, k])


LENS_STEPS = 8
"""Sub-steps of the lens phase of :func:`combined_ball` (its radius is summed at each sub-step's
end: an upper bound, as the lens's radius grows; the excess is at most the phase's length / 8
times the measured speed, under 4 mm for a person walking at 1.5 m/s against 20 m/s^2)."""
ROUND_PAD_M = 1e-9
"""Added to every combined radius: covers the rounding of the closed-form centre integral."""


@njit(types.UniTuple(_f8, 2)(_f8, _f8, _f8, _f8, _f8, _b1), cache=True)
def combined_ball(
    d: float, dv: float, a: float, V: float, tau: float, want_rho: bool = True
) -> tuple[float, float]:
    """The combined speed-and-acceleration model of one joint at ``tau`` after the measurement:
    ``(C, rho)`` such that the joint lies in the ball of centre ``y + C v / |v|`` (``y + v tau``
    direction; ``C = 0`` when ``d = |v| = 0``) and radius ``rho`` (plus the position error
    ``delta_y``, added by the caller), given measured speed ``d``, velocity error bound ``dv``,
    acceleration bound ``a`` and speed bound ``V`` (m, s).

    Derivation. The velocity ``w(s)`` at ``s <= tau`` lies in ``W(s) = B(v, dv + a s) & B(0, V)``
    (the acceleration bound from the measured velocity, the speed bound), so the displacement
    ``int_0^tau w`` lies in the Minkowski integral of ``W``, which lies in the ball with the
    integrated centre and radius of any balls enclosing each ``W(s)``. With ``r = dv + a s``,
    ``A = d^2 + V^2`` and ``x = (A - r^2) / (2 d)`` (the plane of the two spheres' circle),
    the smallest ball enclosing the lens is ``B(v, r)`` while ``x >= d`` (``r^2 <= V^2 - d^2``),
    ``B(x u, sqrt(V^2 - x^2))`` while ``0 < x < d``, ``B(0, V)`` once ``x <= 0`` (``r^2 >= A``).
    A measured speed above ``V + dv`` contradicts the speed bound: the acceleration model's
    ball alone (a person breaking the bounds is the conformance monitor's to catch). The
    centre integrates in closed form (``int x ds =
    (A r - r^3 / 3) / (2 a d)``); the lens radius ``sqrt(V^2 - x^2)`` grows with ``r`` and is
    summed over :data:`LENS_STEPS` sub-steps at their ends (skipped without ``want_rho``: the
    centre alone, for the interval's start and middle). NaN or infinite ``d`` or ``dv`` (no
    velocity estimate): ``B(0, V tau)``, the speed bound alone. Tested against dense sampling of
    bang-bang and random admissible motions (``tests/test_reach_combined.py``)."""
    if not tau > 0.0:
        return 0.0, ROUND_PAD_M
    if not (math.isfinite(d) and math.isfinite(dv)):
        return 0.0, V * tau + ROUND_PAD_M
    if d > V + dv:  # the measurement contradicts the speed bound: the acceleration model alone
        return d * tau, dv * tau + 0.5 * a * tau * tau + ROUND_PAD_M
    A = d * d + V * V
    r_b1 = math.sqrt(V * V - d * d) if d <= V else 0.0  # end of B(v, r) (d > V: none)
    r_b2 = math.sqrt(A)  # start of B(0, V)
    r0, r1 = dv, dv + a * tau
    C, rho = 0.0, 0.0
    # B(v, r): r in [r0, min(r1, r_b1)]
    lo, hi = r0, min(r1, r_b1)
    if hi > lo or a == 0.0 and r0 <= r_b1:
        ds = (hi - lo) / a if a > 0.0 else tau
        C += d * ds
        rho += (hi * hi - lo * lo) / (2.0 * a) if a > 0.0 else r0 * tau
    # the lens: r in (r_b1, r_b2)
    lo, hi = max(r0, r_b1), min(r1, r_b2)
    if d > 0.0 and (hi > lo or a == 0.0 and r_b1 < r0 < r_b2):
        if a > 0.0:
            C += ((A * hi - hi * hi * hi / 3.0) - (A * lo - lo * lo * lo / 3.0)) / (2.0 * a * d)
            step = (hi - lo) / LENS_STEPS
            for i in range(1, LENS_STEPS + 1 if want_rho else 1):
                r = hi if i == LENS_STEPS else lo + i * step
                x = (A - r * r) / (2.0 * d)
                rho += step / a * math.sqrt(max(V * V - x * x, 0.0))
        else:
            x = (A - r0 * r0) / (2.0 * d)
            C += x * tau
            rho += math.sqrt(max(V * V - x * x, 0.0)) * tau
    # B(0, V): r in [max(r0, r_b2), r1]
    lo = max(r0, r_b2)
    if r1 > lo or a == 0.0 and r0 >= r_b2:
        rho += V * ((r1 - lo) / a if a > 0.0 else tau)
    return C, rho + ROUND_PAD_M


@njit(
    types.void(
        _RO3, _RO3, _RO2, _RO1, _RO1, _f8, _RO1, _RO1, _f8, _RO1, _ROI1, _ROI1, _ROI2, _W5, _W3
    ),
    cache=True,
)  # fmt: skip
def combined_sets(
    y: np.ndarray,
    v: np.ndarray,
    dv: np.ndarray,
    t_start_s: np.ndarray,
    t_end_s: np.ndarray,
    delay_s: float,
    a_max: np.ndarray,
    v_max: np.ndarray,
    delta_y_m: float,
    half_thickness_m: np.ndarray,
    ia: np.ndarray,
    ib: np.ndarray,
    end_index: np.ndarray,
    ends: np.ndarray,
    radius: np.ndarray,
) -> None:
    """The combined model's capsules, laid out as :func:`acc_sets`'. Per joint and interval
    ``[tau_a, tau_b]`` the smallest of three balls that are each sound under both bounds (by the
    radius a two-joint part gets from it): the combined ball (:func:`combined_ball`), R_ACC's
    and R_VEL's;
    its centre moves along the measured velocity's direction, monotonically, and its radius
    grows, so the joint's union over the interval lies in the capsule of its centres at
    ``tau_a``, ``tau_b`` with the radius at ``tau_b``; a two-joint part lies in the capsule
    between the joints' mid-interval centres with radius ``R(tau_b)`` + the centre's largest
    distance from its mid-interval place. ``a_max, v_max (J,)``.

    A joint without a velocity estimate (``dv`` infinite) gets R_VEL's ball, so a part whose
    joints all lack one is R_VEL's capsule (unmeasured legs, a person's first frame). A part
    that mixes a joint without an estimate and one with makes no claim (infinite radius): the
    capsule between R_VEL's ball and the neighbour's shifted ball (radius the larger of the
    two) is sound but not monotone in what is known; it could clear a part that the same
    person's capsule with the joint's estimate does not, so a history in which the gate
    distrusted one joint would be less conservative than a fresh measurement
    (``tests/test_ingest_history.py``). The vel model claims R_VEL's capsule for it."""
    H, J, K = y.shape[0], y.shape[1], t_end_s.shape[0]
    X = np.empty(2 * J)
    centre = np.empty((3, J, 3))
    unknown = np.empty(J, dtype=np.bool_)
    for h in range(H):
        for k in range(K):
            ta = t_start_s[k] + delay_s
            tb = t_end_s[k] + delay_s
            tm = 0.5 * (ta + tb)
            for j in range(J):
                vx, vy, vz = v[h, j, 0], v[h, j, 1], v[h, j, 2]
                d = math.sqrt(vx * vx + vy * vy + vz * vz)
                known = math.isfinite(d) and math.isfinite(dv[h, j])
                # three capsules, each sound under both bounds: the combined ball, R_ACC's ball
                # (v tau, dv tau + a tau^2 / 2), R_VEL's (0, V tau); the smallest is used
                Ca = combined_ball(d, dv[h, j], a_max[j], v_max[j], ta, False)[0]
                Cm = combined_ball(d, dv[h, j], a_max[j], v_max[j], tm, False)[0]
                Cb, rho = combined_ball(d, dv[h, j], a_max[j], v_max[j], tb, True)
                best = rho + max(Cb - Cm, Cm - Ca)
                acc = dv[h, j] * tb + 0.5 * a_max[j] * tb * tb
                if known and acc + d * (tb - tm) < best:
                    Ca, Cm, Cb, rho, best = d * ta, d * tm, d * tb, acc, acc + d * (tb - tm)
                if v_max[j] * tb < best or not known:
                    Ca, Cm, Cb, rho = 0.0, 0.0, 0.0, v_max[j] * tb
                unknown[j] = not known
                f = 1.0 / d if known and d > 0.0 else 0.0
                for r in range(3):
                    u = v[h, j, r] * f
                    centre[0, j, r] = y[h, j, r] + u * Ca
                    centre[1, j, r] = y[h, j, r] + u * Cm
                    centre[2, j, r] = y[h, j, r] + u * Cb
                R = rho + delta_y_m
                X[j] = R
                X[J + j] = R + max(Cb - Cm, Cm - Ca)
            _parts(X, centre, half_thickness_m, ia, ib, end_index, ends[h, k], radius[h, k])
            for p in range(ia.shape[0]):  # a part mixing known and unknown joints: no claim
                if unknown[ia[p] % J] != unknown[ib[p] % J]:
                    radius[h, k, p] = math.inf


STATIC = types.Tuple((_ROI2, _RO2, _RO2, _RO3, _f8))
"""``(part_joints (P, 2), base_m (2, P), speed_mps (2, P), disp_m (2, P, N), disp_step_s)``:
rows vel, iso13855 (the displacement bound is R_VEL's; ISO 13855's row is ``inf``)."""
ACC = types.Tuple((_RO1, _RO1, _ROI1, _ROI1, _ROI2, _RO1, _RO1))
"""``(a_half (J,), half_thickness_m (P,), ia, ib (P,), end_index (P, 2), a_max, v_max (J,))``:
R_ACC's and the combined model's."""
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
    (ke, C, 2, 3), radius (k, C), ke)`` views of ``buffers``, ``ke = k`` for ACC and the
    combined model (which share the ACC buffers), else 1 (the
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
    if kind == KIND_ACC or kind == KIND_COMBINED:
        a_half, half_thickness, ia, ib, end_index, a_max, v_max = acc
        if kind == KIND_ACC:
            acc_sets(yh, v[h : h + 1], dv[h : h + 1], ts, te, delay_s, a_half, delta_y_m,
                     half_thickness, ia, ib, end_index, acc_e[:, :k], acc_r[:, :k])  # fmt: skip
        else:
            combined_sets(yh, v[h : h + 1], dv[h : h + 1], ts, te, delay_s, a_max, v_max,
                          delta_y_m, half_thickness, ia, ib, end_index, acc_e[:, :k],
                          acc_r[:, :k])  # fmt: skip
        return acc_e[0, :k], acc_r[0, :k], k
    if kind == KIND_POS:
        pos_sets(yh, pos[0], pos[1], pos[2], pos[3], te, delay_s, pos[4], pos[5], n_limbs,
                 pos_e, pos_r[:, :k])  # fmt: skip
        return pos_e[0:1], pos_r[0, :k], 1
    row = 0 if kind == KIND_VEL else 1
    part_joints, base, speed, disp, disp_step = static
    static_sets(yh, part_joints, te, delay_s, base[row], speed[row], disp[row], disp_step, st_e,
                st_r[:k])  # fmt: skip
    return st_e[0:1], st_r[:k], 1


CONSTANTS = types.Tuple((STATIC, ACC, POS, types.UniTuple(_f8, 2), _i8))
"""``(static, acc, pos, (delay_s, delta_y_m), n_limbs)``: ``HumanReach.kernel_constants``."""
BUFFERS = types.Tuple((_W1, _W1, _W5, _W3, _W4, _W2, _W4, _W3))
""":func:`person_sets`'s buffers (its docstring gives their shapes)."""


@njit(types.void(_i8, _RO3, _RO3, _RO2, _RO1, _RO1, CONSTANTS, BUFFERS, _W4, _W2), cache=True)
def people_sets(
    kind: int,
    y: np.ndarray,
    v: np.ndarray,
    dv: np.ndarray,
    age_s: np.ndarray,
    times: np.ndarray,
    constants: Any,
    buffers: Any,
    out_ends: np.ndarray,
    out_radius: np.ndarray,
) -> None:
    """Every person's capsules of model ``kind`` on one interval, each from their own
    measurement: person ``h`` on ``[age_s[h] + times[0], age_s[h] + times[1]]`` (``y, v (H, J,
    3)``, ``dv (H, J)``, ``age_s (H,)``, ``times (2,)``); into ``out_ends (H, C, 2, 3)``,
    ``out_radius (H, C)``. :func:`person_sets` per person with buffers for one interval: the
    sets the checks compute, in one call for all the people (a display of many people)."""
    human = (y, v, dv)
    for h in range(age_s.shape[0]):
        ends, radius, _ = person_sets(kind, h, human, age_s[h], times, 0, 1, constants, buffers)
        out_ends[h] = ends[0]
        out_radius[h] = radius[0]
