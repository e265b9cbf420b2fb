"""The tracking gate's per-frame checks, compiled (:mod:`sara_app.human.gate` states the three
conditions and what a held joint's set is; ``tests/gate_reference.py`` is the plain numpy
oracle).

One call per frame and person: the jump, bone and frozen checks of every joint, the flags, the
speed a joint that only jumped needed, the hold bookkeeping and the trusted positions. With
the numpy version ``Gate.check`` cost 49 us per frame (some forty small array operations on
``(J, 3)`` arrays), with this one 4.5 us (a warm loop, 2026-11-28); the enclosure of held
joints (rare) stays in numpy (:func:`~sara_app.human.gate.enclose`).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from sara_app.kernel_types import F8, I8, RO1, RO2, ROB1, ROI2, W1, W2, WB1, WB2

ALL_GOOD, FLAGGED, CLEAN, REFUSED = 1, 2, 4, 8
"""Bits of :func:`gate_frame`'s result: every joint trusted; some joint flagged; no measured
joint held or jumping (the frame may teach bone lengths); the frame is refused."""

FROZEN_EPS_M = 1e-9
"""A coordinate change below this is a repeat (a frozen output, not motion or noise)."""


@njit(
    types.int64(F8, RO2, F8, I8, ROB1, RO1, ROI2, RO1, RO1, RO1, F8, F8,
                W2, W1, W1, RO2, RO1, W1, WB2, W1, WB1, WB1),
    cache=True,
)  # fmt: skip
def gate_frame(
    t_s: float,
    y: np.ndarray,
    delta_y_m: float,
    n_measured: int,
    lost: np.ndarray,
    v_max_mps: np.ndarray,
    bones: np.ndarray,
    length_m: np.ndarray,
    shortest_m: np.ndarray,
    longest_m: np.ndarray,
    bone_tol_m: float,
    max_hold_s: float,
    y_trusted: np.ndarray,
    t_trusted: np.ndarray,
    dy_trusted: np.ndarray,
    y_prev: np.ndarray,
    first_seen_s: np.ndarray,
    since_s: np.ndarray,
    flags: np.ndarray,
    jump_speed_mps: np.ndarray,
    trusted: np.ndarray,
    same: np.ndarray,
) -> int:
    """Check the frame ``y (J, 3)`` (missing joints ``lost (J,)`` already replaced by their
    trusted positions) stamped ``t_s``: write ``flags (J, 4)`` (jump, bone, frozen, missing),
    ``jump_speed_mps (J,)``, ``trusted (J,)`` and ``same (J,)`` (a measured joint repeated
    exactly), update the gate's state ``y_trusted (J, 3)``, ``t_trusted``, ``dy_trusted``,
    ``since_s`` (all ``(J,)``) in place; ``y_prev`` and ``first_seen_s`` are read only (the
    caller advances them after enclosing the held joints). ``bones (B, 2)``, ``length_m (B,)``
    (nan: not known); a bone is inconsistent when off its length by more than the noise and
    ``bone_tol_m``, or outside ``[shortest_m, longest_m] (B,)`` (a person's: always known) by
    more than the noise. Returns the bits :data:`ALL_GOOD`, :data:`FLAGGED`, :data:`CLEAN`,
    :data:`REFUSED`."""
    J = y.shape[0]
    noise = 2.0 * delta_y_m
    # no work arrays: jump and frozen live in their flag columns, each joint's distance from
    # its trusted position in jump_speed_mps until the last pass; "measured" and "held" (the
    # hold as it stood before this frame) are recomputed where read
    any_moved = False
    for j in range(J):
        measured = j < n_measured and not lost[j]
        d2 = 0.0
        rep = True
        for c in range(3):
            e = y[j, c] - y_trusted[j, c]
            d2 += e * e
            rep = rep and abs(y[j, c] - y_prev[j, c]) <= FROZEN_EPS_M
        jump_speed_mps[j] = math.sqrt(d2)
        reach = noise + v_max_mps[j] * (t_s - t_trusted[j])
        flags[j, 0] = measured and math.isfinite(t_trusted[j]) and jump_speed_mps[j] > reach
        same[j] = measured and rep
        if measured and not same[j] and math.isfinite(y_prev[j, 0]):
            any_moved = True
    for j in range(J):
        flags[j, 1] = False
        flags[j, 2] = same[j] and (any_moved or math.isfinite(since_s[j]))
        flags[j, 3] = lost[j]
    for k in range(bones.shape[0]):  # an inconsistent bone blames its suspect ends, else both
        a, b = bones[k, 0], bones[k, 1]
        if not (a < n_measured and not lost[a] and b < n_measured and not lost[b]):
            continue
        d2 = 0.0
        for c in range(3):
            e = y[a, c] - y[b, c]
            d2 += e * e
        length = math.sqrt(d2)
        # NaN (a non-finite joint, which the decoder refuses first) is not judged, as before
        person = not (length < shortest_m[k] - noise or length > longest_m[k] + noise)
        if person and not abs(length - length_m[k]) > noise + bone_tol_m:  # nan: not known
            continue
        sa = flags[a, 0] or flags[a, 2] or math.isfinite(since_s[a])
        sb = flags[b, 0] or flags[b, 2] or math.isfinite(since_s[b])
        if sa or not sb:
            flags[a, 1] = True
        if sb or not sa:
            flags[b, 1] = True
    result = ALL_GOOD | CLEAN
    for j in range(J):
        jump, frozen, held = flags[j, 0], flags[j, 2], math.isfinite(since_s[j])
        glitch = flags[j, 1] or frozen or lost[j]
        bad = glitch or jump
        if jump and not glitch:
            jump_speed_mps[j] = (jump_speed_mps[j] - noise) / (t_s - t_trusted[j])
        else:
            jump_speed_mps[j] = 0.0
        # a frozen joint's repeated value was a measurement when it first came: held from then
        if frozen and t_trusted[j] > first_seen_s[j]:
            t_trusted[j] = first_seen_s[j]
            for c in range(3):
                y_trusted[j, c] = y[j, c]
        if bad:
            result |= FLAGGED
            result &= ~ALL_GOOD
            if j < n_measured and not lost[j]:
                result &= ~CLEAN
            if not held:
                since_s[j] = min(first_seen_s[j], t_s) if frozen else t_s
            if t_s - since_s[j] > max_hold_s:
                result |= REFUSED
        else:
            since_s[j] = np.nan
            for c in range(3):
                y_trusted[j, c] = y[j, c]
            t_trusted[j] = t_s
            dy_trusted[j] = delta_y_m
        trusted[j] = not bad
        if lost[j] and not math.isfinite(t_trusted[j]):
            result |= REFUSED
    return result


@njit(types.void(F8, RO2, ROB1, W1, W2), cache=True)
def gate_advance(
    t_s: float, y: np.ndarray, same: np.ndarray, first_seen_s: np.ndarray, y_prev: np.ndarray
) -> None:
    """After a frame: a joint's value is new (first seen at ``t_s``) unless it repeated
    (``same (J,)``); ``y (J, 3)`` is the previous frame of the next one."""
    for j in range(y.shape[0]):
        if not same[j]:
            first_seen_s[j] = t_s
        for c in range(3):
            y_prev[j, c] = y[j, c]


@njit(types.boolean(RO2, W2, I8, ROB1), cache=True)
def repeated_frame(y: np.ndarray, raw: np.ndarray, n_measured: int, missing: np.ndarray) -> bool:
    """The stale-tracker rule's repeat test (``Intake._repeated``): whether the measured joints
    of ``y (J, 3)`` (the first ``n_measured``, less ``missing (J,)``; at least one) all repeat
    ``raw (J, 3)``, the previous frame as measured, within :data:`FROZEN_EPS_M` (NaN: not a
    repeat); when they do not, ``raw`` becomes ``y``. It was eight numpy calls per frame (7 us
    in a warm loop, about 30 us live)."""
    J = y.shape[0]
    seen, same = False, True
    for j in range(min(n_measured, J)):
        if missing[j]:
            continue
        seen = True
        for c in range(3):
            if not abs(y[j, c] - raw[j, c]) <= FROZEN_EPS_M:
                same = False
    same = same and seen
    if not same:
        for j in range(J):
            for c in range(3):
                raw[j, c] = y[j, c]
    return same
