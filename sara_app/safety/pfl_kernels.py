"""Compiled kernels of the PFL verdict (:mod:`sara_app.safety.pfl`) and of the speed scaling
(:mod:`sara_app.safety.pfl_shield`): eq. 7's thresholds per entry, the verdict of one model's
classification, the per-entry merge of further models and its summary, the candidate path speed
of the violated (or touching) entries and whether interval 0 is already too fast. Explicit
signatures (read-only ``'A'`` inputs), ``cache=True``: compiled or loaded at import.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from sara_app.kernel_types import RO1 as _RO1
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import RO3 as _RO3
from sara_app.kernel_types import ROB3 as _ROB3
from sara_app.kernel_types import ROI8_3 as _ROI3
from sara_app.kernel_types import W2 as _W2
from sara_app.kernel_types import W3 as _W3
from sara_app.kernel_types import WB1 as _WB1
from sara_app.kernel_types import WB3 as _WB3
from sara_app.kernel_types import WI1 as _WI1
from sara_app.kernel_types import WI2 as _WI2
from sara_app.kernel_types import WI8_3 as _WI83

__all__ = [
    "entry_thresholds",
    "merge_kernel",
    "speed_kernel",
    "stuck_kernel",
    "summary_kernel",
    "verdict_kernel",
]


@njit(types.void(_ROB3, _ROI3, _RO2, _RO2, _W3), cache=True)
def entry_thresholds(
    stack: np.ndarray,
    cls: np.ndarray,
    T_clamp: np.ndarray,
    T_free: np.ndarray,
    thr: np.ndarray,
) -> None:
    """Eq. 7's threshold ``thr (k, L, P)`` of every entry of a classification ``stack (k, P,
    P)``, ``cls (k, L, P)``: constrained (``cls >= 2``) the smallest ``T_clamp[i, m]`` over the
    stack ``m`` of part ``j``, else ``T_free[i, j]``. One pass filling an array, not a helper
    per entry: a compiled call with array arguments costs ~20 ns (reference counting), which
    made the verdict 4x slower. The minimum over a stack is computed once per link and stack
    (parts whose stack rows are equal share it; a classification's stacks are a partition, but
    a row that differs from its first member's is computed on its own): near a person most
    entries are constrained and this loop was most of the verdict (11 of 15 us)."""
    K, L, P = cls.shape
    rep = np.empty(P, dtype=np.int64)
    t_min = np.empty(P)
    for k in range(K):
        for j in range(P):  # the first member of j's stack, if its row is j's
            r = -1
            for m in range(P):
                if stack[k, j, m]:
                    r = m
                    break
            if r >= 0:
                for m in range(P):
                    if stack[k, j, m] != stack[k, r, m]:
                        r = -1
                        break
            rep[j] = r
        for i in range(L):
            for j in range(P):
                t_min[j] = np.nan  # not computed
            for j in range(P):
                if cls[k, i, j] < 2:
                    thr[k, i, j] = T_free[i, j]
                    continue
                r = rep[j]
                if r >= 0 and t_min[r] == t_min[r]:
                    thr[k, i, j] = t_min[r]
                    continue
                t = np.inf
                for m in range(P):
                    if stack[k, j, m] and T_clamp[i, m] < t:
                        t = T_clamp[i, m]
                thr[k, i, j] = t
                if r >= 0:
                    t_min[r] = t


@njit(
    types.void(_ROB3, _ROI3, _ROB3, _RO2, _RO2, _RO2, types.int64, _WB3, _WI83, _W3, _WI1),
    cache=True,
)
def merge_kernel(
    stack: np.ndarray,
    cls: np.ndarray,
    contact: np.ndarray,
    T_clamp: np.ndarray,
    T_free: np.ndarray,
    E_int: np.ndarray,
    lo: int,
    safe: np.ndarray,
    cls_m: np.ndarray,
    thr_m: np.ndarray,
    todo: np.ndarray,
) -> None:
    """Merge one more model's classification of intervals ``lo:lo+k`` (``stack (k, P, P)``,
    ``cls, contact (k, L, P)``) into the merged verdict ``safe, cls_m, thr_m (K, L, P)``: an
    entry not yet proved takes this model's class and threshold (as in :func:`verdict_kernel`)
    when this model proves it (eq. 7 with ``E_int (K, L)``) or when its threshold is higher.
    ``todo (2,)``: first and last interval with an unproved entry (-1, -1: none)."""
    k_n, L, P = cls.shape
    first, last = -1, -1
    thr = np.empty((k_n, L, P))
    entry_thresholds(stack, cls, T_clamp, T_free, thr)
    for kk in range(k_n):
        k = lo + kk
        ok_k = True
        for i in range(L):
            for j in range(P):
                if safe[k, i, j]:
                    continue
                t = thr[kk, i, j]
                if not contact[kk, i, j] or t - E_int[k, i] > 0.0:
                    safe[k, i, j] = True
                    cls_m[k, i, j] = cls[kk, i, j]
                    thr_m[k, i, j] = t
                else:
                    ok_k = False
                    if t > thr_m[k, i, j]:
                        cls_m[k, i, j] = cls[kk, i, j]
                        thr_m[k, i, j] = t
        if not ok_k:
            if first < 0:
                first = k
            last = k
    todo[0], todo[1] = first, last


@njit(types.void(_ROI3, _RO3, _RO2, _ROB3, _W3, _WB1, _W2, _WI2), cache=True)
def summary_kernel(
    cls: np.ndarray,
    thr: np.ndarray,
    E_int: np.ndarray,
    safe: np.ndarray,
    margin: np.ndarray,
    safe_k: np.ndarray,
    allowed: np.ndarray,
    part: np.ndarray,
) -> None:
    """The per-entry and per-link summaries of a merged verdict (as :func:`verdict_kernel`
    from the merged ``cls, thr, safe (K, L, P)``): ``margin = thr - E_int``, ``safe_k``, and
    per ``(k, i)`` the smallest threshold over the parts in contact and its first part."""
    K, L, P = cls.shape
    for k in range(K):
        ok_k = True
        for i in range(L):
            best, arg = np.inf, 0
            for j in range(P):
                t = thr[k, i, j]
                margin[k, i, j] = t - E_int[k, i]
                ok_k = ok_k and safe[k, i, j]
                if cls[k, i, j] > 0 and t < best:
                    best, arg = t, j
            allowed[k, i] = best
            part[k, i] = arg if math.isfinite(best) else -1
        safe_k[k] = ok_k


@njit(
    types.void(_ROB3, _ROI3, _ROB3, _RO2, _RO2, _RO2, _W3, _W3, _WB3, _WB1, _W2, _WI2),
    cache=True,
)
def verdict_kernel(
    stack: np.ndarray,
    cls: np.ndarray,
    contact: np.ndarray,
    T_clamp: np.ndarray,
    T_free: np.ndarray,
    E_int: np.ndarray,
    thr: np.ndarray,
    margin: np.ndarray,
    safe: np.ndarray,
    safe_k: np.ndarray,
    allowed: np.ndarray,
    part: np.ndarray,
) -> None:
    """Eq. 7 per interval ``k``, link ``i``, part ``j``: the threshold ``thr`` (constrained: the
    smallest ``T_clamp[i, m]`` over the stack ``m`` of ``j``, where ``cls >= 2``; else
    ``T_free[i, j]``), ``safe = ~contact | thr - E_int[k, i] > 0`` (NaN energy: unsafe), then
    :func:`summary_kernel`'s ``margin``, ``safe_k``, ``allowed`` and ``part`` (a classification
    has ``contact == (cls > 0)``, tested)."""
    K, L, P = cls.shape
    entry_thresholds(stack, cls, T_clamp, T_free, thr)
    for k in range(K):
        for i in range(L):
            e = E_int[k, i]
            for j in range(P):
                safe[k, i, j] = not contact[k, i, j] or thr[k, i, j] - e > 0.0
    summary_kernel(cls, thr, E_int, safe, margin, safe_k, allowed, part)


@njit(types.float64(types.boolean, _ROB3, _ROI3, _RO3, _RO2, _RO1), cache=True, error_model="numpy")
def speed_kernel(
    violated: bool,
    safe: np.ndarray,
    cls: np.ndarray,
    thr: np.ndarray,
    E: np.ndarray,
    sd: np.ndarray,
) -> float:
    """Smallest ``s' sqrt(T / E)`` over the entries ``(k, i, j)`` that are unsafe (``violated``)
    or in contact (``cls > 0``), with ``s'`` the larger path speed at the ends of interval
    ``k`` (``sd (K+1,)``), ``T = thr[k, i, j]``, ``E = E[k, i]``; ``inf`` if none; a NaN
    candidate counts as 0 (as the numpy reference in the tests)."""
    K, L, P = cls.shape
    best = np.inf
    for k in range(K):
        speed = max(abs(sd[k]), abs(sd[k + 1]))
        for i in range(L):
            for j in range(P):
                if (not safe[k, i, j]) if violated else cls[k, i, j] > 0:
                    c = speed * math.sqrt(thr[k, i, j] / E[k, i])
                    if c != c:
                        c = 0.0
                    if c < best:
                        best = c
    return best


@njit(types.boolean(_ROB3, _RO3, _RO1), cache=True)
def stuck_kernel(safe: np.ndarray, thr: np.ndarray, E0: np.ndarray) -> bool:
    """Some entry of interval 0 is unsafe (``safe (K, L, P)``) while its link's energy at the
    current state ``E0 (L,)`` is not below the entry's threshold ``thr (K, L, P)``: no slower
    plan can fix it (NaN counts as stuck)."""
    for i in range(safe.shape[1]):
        for j in range(safe.shape[2]):
            if not safe[0, i, j] and not E0[i] < thr[0, i, j]:
                return True
    return False
