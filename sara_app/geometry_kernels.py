"""Compiled (numba) capsule kernels of the verification hot paths.

Same mathematics as :func:`sara_app.geometry.segment_segment_closest` (and tested against it,
``tests/test_geometry_kernels.py``), written as loops: at the sizes of one control cycle (a few
hundred to a few thousand capsule pairs) numpy spends most of its time in per-call overhead
(about 1-3 us per array operation here), a loop over the pairs does not.

Conventions (as in :mod:`sara_app.geometry`): capsule sets are ``ends (..., 2, 3)`` (m) and
``radius (...)`` (m). NaN never makes a pair look separated: every predicate is written as
``not (d > 0)`` for "may touch", so a NaN distance counts as contact.

Compilation: every kernel has an explicit signature (read-only ``'A'``-layout arrays, so views
and broadcast arrays are accepted without a new specialisation) and ``cache=True``: it is
compiled (or loaded from numba's cache) when this module is imported, never on a first call in
a control loop, and no call can trigger a compilation. All kernels that call each other live in
this one file, because numba's cache does not notice changes in other files.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

__all__ = ["capsule_sets_check", "segment_closest", "sphere_slack_m"]

_PARALLEL_SIN2 = 1e-24  # as in sara_app.geometry
sphere_slack_m = 1e-9
"""A bounding-sphere lower bound must exceed this (m) before a pair is skipped: covers the
round-off of the bound itself, so a skipped pair is separated by more than its rounding."""

_f8 = types.float64
_RO4 = types.Array(_f8, 4, "A", readonly=True)
_RO2 = types.Array(_f8, 2, "A", readonly=True)
_ROB1 = types.Array(types.boolean, 1, "A", readonly=True)
_WB1 = types.Array(types.boolean, 1, "A")


@njit(cache=True)
def segment_closest(
    p1x: float, p1y: float, p1z: float, q1x: float, q1y: float, q1z: float,
    p2x: float, p2y: float, p2z: float, q2x: float, q2y: float, q2z: float,
) -> tuple[float, float, float]:  # fmt: skip
    """Closest points of segments ``[p1, q1]`` and ``[p2, q2]``: ``(distance, s, t)``, the
    branches of :func:`sara_app.geometry.segment_segment_closest` (points, parallel pairs)."""
    d1x, d1y, d1z = q1x - p1x, q1y - p1y, q1z - p1z
    d2x, d2y, d2z = q2x - p2x, q2y - p2y, q2z - p2z
    rx, ry, rz = p1x - p2x, p1y - p2y, p1z - p2z
    a = d1x * d1x + d1y * d1y + d1z * d1z
    e = d2x * d2x + d2y * d2y + d2z * d2z
    b = d1x * d2x + d1y * d2y + d1z * d2z
    c = d1x * rx + d1y * ry + d1z * rz
    f = d2x * rx + d2y * ry + d2z * rz
    nx, ny, nz = d1y * d2z - d1z * d2y, d1z * d2x - d1x * d2z, d1x * d2y - d1y * d2x
    denom = nx * nx + ny * ny + nz * nz
    s = 0.0
    if denom > _PARALLEL_SIN2 * a * e:
        mx, my, mz = d2y * rz - d2z * ry, d2z * rx - d2x * rz, d2x * ry - d2y * rx
        s = (nx * mx + ny * my + nz * mz) / denom
    if not a > 0.0:
        s = 0.0
    s = 0.0 if s < 0.0 else (1.0 if s > 1.0 else s)
    t = (b * s + f) / e if e > 0.0 else -1.0
    tc = 0.0 if t < 0.0 else (1.0 if t > 1.0 else t)
    if t != tc:
        if a > 0.0:
            s = (b * tc - c) / a
            s = 0.0 if s < 0.0 else (1.0 if s > 1.0 else s)
        else:
            s = 0.0
    gx = rx + s * d1x - tc * d2x
    gy = ry + s * d1y - tc * d2y
    gz = rz + s * d1z - tc * d2z
    return math.sqrt(gx * gx + gy * gy + gz * gz), s, tc


@njit(cache=True)
def _spheres(ends: np.ndarray, radius: np.ndarray, out: np.ndarray) -> None:
    """Bounding spheres of capsules ``ends (N, 2, 3)``, ``radius (1, N)``, written to ``out (N,
    4)``: midpoint, then half length + radius."""
    for i in range(ends.shape[0]):
        hx = 0.5 * (ends[i, 1, 0] - ends[i, 0, 0])
        hy = 0.5 * (ends[i, 1, 1] - ends[i, 0, 1])
        hz = 0.5 * (ends[i, 1, 2] - ends[i, 0, 2])
        out[i, 0] = ends[i, 0, 0] + hx
        out[i, 1] = ends[i, 0, 1] + hy
        out[i, 2] = ends[i, 0, 2] + hz
        out[i, 3] = math.sqrt(hx * hx + hy * hy + hz * hz) + radius[0, i]


@njit(_f8(_RO4, _RO2, _RO4, _RO2, _ROB1, _WB1), cache=True)
def capsule_sets_check(
    a_ends: np.ndarray,
    a_radius: np.ndarray,
    b_ends: np.ndarray,
    b_radius: np.ndarray,
    todo: np.ndarray,
    hit: np.ndarray,
) -> float:
    """Per interval, whether two capsule sets may touch, and their exact smallest distance.

    ``a_ends (Ka, C, 2, 3)``, ``a_radius (Kr, C)`` with ``Ka, Kr`` in ``{1, K}`` (1: the same
    capsules on every interval); ``b_ends (K, L, 2, 3)``, ``b_radius (K, L)``; ``todo (K,)``:
    the intervals to check. Writes ``hit (K,)``: some pair of interval ``k`` may touch (surface
    distance <= 0 or NaN; False outside ``todo``). Returns the smallest surface distance over
    all pairs of the checked intervals (exact, negative: overlap; ``inf`` when none is checked).

    Bounding spheres prune: a pair is skipped only when the spheres' gap exceeds
    :data:`sphere_slack_m` and cannot improve the smallest distance found so far.
    """
    K, C, L = b_ends.shape[0], a_ends.shape[1], b_ends.shape[1]
    sa = np.empty((C, 4))
    sb = np.empty((L, 4))
    best = np.inf
    ka_prev = kr_prev = -1
    for k in range(K):
        hit[k] = False
        if not todo[k]:
            continue
        ka = k if a_ends.shape[0] == K else 0
        kr = k if a_radius.shape[0] == K else 0
        if ka != ka_prev or kr != kr_prev:
            _spheres(a_ends[ka], a_radius[kr : kr + 1], sa)
            ka_prev, kr_prev = ka, kr
        _spheres(b_ends[k], b_radius[k : k + 1], sb)
        for c in range(C):
            for l in range(L):
                dx = sa[c, 0] - sb[l, 0]
                dy = sa[c, 1] - sb[l, 1]
                dz = sa[c, 2] - sb[l, 2]
                lower = math.sqrt(dx * dx + dy * dy + dz * dz) - sa[c, 3] - sb[l, 3]
                if lower >= best and (lower > sphere_slack_m or hit[k]):
                    continue
                p, q = a_ends[ka, c], b_ends[k, l]
                d = segment_closest(
                    p[0, 0], p[0, 1], p[0, 2], p[1, 0], p[1, 1], p[1, 2],
                    q[0, 0], q[0, 1], q[0, 2], q[1, 0], q[1, 1], q[1, 2],
                )[0] - a_radius[kr, c] - b_radius[k, l]  # fmt: skip
                if not d > 0.0:
                    hit[k] = True
                if d < best:
                    best = d
    return best
