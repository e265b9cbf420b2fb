"""Compiled (numba) capsule kernels of the verification hot paths.

Same mathematics as :func:`sara_app.geometry.shapes.segment_segment_closest` (and tested against it,
``tests/test_shape_kernels.py``), written as loops: at the sizes of one control cycle (a few
hundred to a few thousand capsule pairs) numpy spends most of its time in per-call overhead
(about 1-3 us per array operation here), a loop over the pairs does not.

Conventions (as in :mod:`sara_app.geometry.shapes`): capsule sets are ``ends (..., 2, 3)`` (m) and
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

from sara_app.kernel_types import F8 as _f8
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import RO3 as _RO3
from sara_app.kernel_types import RO4 as _RO4
from sara_app.kernel_types import ROB1 as _ROB1
from sara_app.kernel_types import W3 as _W3
from sara_app.kernel_types import W4 as _W4
from sara_app.kernel_types import WB1 as _WB1

__all__ = [
    "below_gaps",
    "bounding_spheres",
    "box_axis_gaps",
    "box_entry",
    "capsule_sets_check",
    "gap_block",
    "lowest_z",
    "pair_gaps",
    "point_segment_gap",
    "segment_closest",
    "set_gap_interval",
    "set_gap_scratch",
    "set_neighbours",
    "set_pair_entry",
    "sphere_gap",
    "sphere_slack_m",
]

_PARALLEL_SIN2 = 1e-24  # as in sara_app.geometry.shapes
sphere_slack_m = 1e-9
"""A bounding-sphere lower bound must exceed this (m) before a pair is skipped: covers the
round-off of the bound itself, so a skipped pair is separated by more than its rounding."""


@njit(types.UniTuple(types.float64, 3)(*([types.float64] * 12)), cache=True)
def segment_closest(
    p1x: float, p1y: float, p1z: float, q1x: float, q1y: float, q1z: float,
    p2x: float, p2y: float, p2z: float, q2x: float, q2y: float, q2z: float,
) -> tuple[float, float, float]:  # fmt: skip
    """Closest points of segments ``[p1, q1]`` and ``[p2, q2]``: ``(distance, s, t)``, the
    branches of :func:`sara_app.geometry.shapes.segment_segment_closest` (points, parallel
    pairs)."""
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


@njit(types.float64(*([types.float64] * 9)), cache=True)
def point_segment_gap(
    px: float, py: float, pz: float, ax: float, ay: float, az: float,
    bx: float, by: float, bz: float,
) -> float:  # fmt: skip
    """Distance from point ``p`` to segment ``[a, b]``
    (:func:`sara_app.geometry.shapes.point_segment_closest`: only an exactly degenerate segment
    is a point; the parameter is clipped as ``np.clip``, which keeps NaN). Its sums of three
    products run left to right, where numpy's ``einsum`` adds in an order of its own: a
    result may differ from numpy's in its last bits."""
    dx, dy, dz = bx - ax, by - ay, bz - az
    dd = dx * dx + dy * dy + dz * dz
    s = ((px - ax) * dx + (py - ay) * dy + (pz - az) * dz) / (dd if dd > 0.0 else 1.0)
    if s < 0.0:
        s = 0.0
    elif s > 1.0:
        s = 1.0
    gx, gy, gz = px - (ax + s * dx), py - (ay + s * dy), pz - (az + s * dz)
    return math.sqrt(gx * gx + gy * gy + gz * gz)


@njit(cache=True)
def bounding_spheres(ends: np.ndarray, radius: np.ndarray, out: np.ndarray) -> None:
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


@njit(cache=True)
def sphere_gap(sa: np.ndarray, i: int, sb: np.ndarray, j: int) -> float:
    """Gap between bounding spheres ``sa[i]`` and ``sb[j]`` (rows of
    :func:`bounding_spheres`): a lower bound of the two capsules' surface distance (NaN stays
    NaN)."""
    dx, dy, dz = sa[i, 0] - sb[j, 0], sa[i, 1] - sb[j, 1], sa[i, 2] - sb[j, 2]
    return math.sqrt(dx * dx + dy * dy + dz * dz) - sa[i, 3] - sb[j, 3]


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
            bounding_spheres(a_ends[ka], a_radius[kr : kr + 1], sa)
            ka_prev, kr_prev = ka, kr
        bounding_spheres(b_ends[k], b_radius[k : k + 1], sb)
        for c in range(C):
            for l in range(L):
                lower = sphere_gap(sa, c, sb, l)
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


@njit(cache=True)
def _pairs(
    a_ends: np.ndarray,
    a_radius: np.ndarray,
    b_ends: np.ndarray,
    b_radius: np.ndarray,
    out: np.ndarray,
    prune: bool,
) -> bool:
    """:func:`pair_distances` (``prune`` False) or :func:`pair_gaps` (True)."""
    K, A, B = out.shape
    sa = np.empty((A if prune else 0, 4))
    sb = np.empty((B if prune else 0, 4))
    a_prev = b_prev = (-1, -1)
    touch = False
    for k in range(K):
        ka = k if a_ends.shape[0] == K else 0
        kb = k if b_ends.shape[0] == K else 0
        kra = k if a_radius.shape[0] == K else 0
        krb = k if b_radius.shape[0] == K else 0
        if prune and (ka, kra) != a_prev:
            bounding_spheres(a_ends[ka], a_radius[kra : kra + 1], sa)
            a_prev = (ka, kra)
        if prune and (kb, krb) != b_prev:
            bounding_spheres(b_ends[kb], b_radius[krb : krb + 1], sb)
            b_prev = (kb, krb)
        for i in range(A):
            for j in range(B):
                if prune:
                    lower = sphere_gap(sa, i, sb, j)
                    if lower > sphere_slack_m:  # NaN goes on to the exact distance
                        out[k, i, j] = lower
                        continue
                d = segment_closest(
                    a_ends[ka, i, 0, 0], a_ends[ka, i, 0, 1], a_ends[ka, i, 0, 2],
                    a_ends[ka, i, 1, 0], a_ends[ka, i, 1, 1], a_ends[ka, i, 1, 2],
                    b_ends[kb, j, 0, 0], b_ends[kb, j, 0, 1], b_ends[kb, j, 0, 2],
                    b_ends[kb, j, 1, 0], b_ends[kb, j, 1, 1], b_ends[kb, j, 1, 2],
                )[0]  # fmt: skip
                g = d - a_radius[kra, i] - b_radius[krb, j]
                out[k, i, j] = g
                touch = touch or not g > 0.0
    return touch


@njit(types.boolean(_RO4, _RO2, _RO4, _RO2, _W3), cache=True)
def pair_distances(
    a_ends: np.ndarray,
    a_radius: np.ndarray,
    b_ends: np.ndarray,
    b_radius: np.ndarray,
    out: np.ndarray,
) -> bool:
    """Surface distances ``out (K, A, B)`` of every pair of capsules ``a (Ka, A, 2, 3), (Ka,
    A)`` and ``b (Kb, B, 2, 3), (Kb, B)`` per interval, ``Ka, Kb`` in ``{1, K}`` (1: the same
    capsules on every interval); as :func:`sara_app.geometry.shapes.capsule_distances`. Returns
    whether any pair may touch (a distance <= 0 or NaN)."""
    return _pairs(a_ends, a_radius, b_ends, b_radius, out, False)


@njit(types.boolean(_RO4, _RO2, _RO4, _RO2, _W3), cache=True)
def pair_gaps(
    a_ends: np.ndarray,
    a_radius: np.ndarray,
    b_ends: np.ndarray,
    b_radius: np.ndarray,
    out: np.ndarray,
) -> bool:
    """:func:`pair_distances` with a bounding-sphere broad phase: ``out (K, A, B)`` is the exact
    surface distance of every pair whose bounding spheres' gap is at most
    :data:`sphere_slack_m`, and that gap (a lower bound of the distance, > the slack) for the
    others. So ``out <= 0`` (or NaN) exactly where the capsules may touch, which is all a
    contact test needs; 2-3x faster when most pairs are apart. Returns whether any pair may
    touch."""
    return _pairs(a_ends, a_radius, b_ends, b_radius, out, True)


@njit(cache=True)
def lowest_z(z_a: float, z_b: float, radius: float) -> float:
    """The lowest height of a capsule whose ends are at heights ``z_a``, ``z_b``; ``-inf``
    when any is NaN (as low as can be)."""
    low = (z_a if z_a < z_b else z_b) - radius
    return low if low == low and z_a == z_a and z_b == z_b else -np.inf


@njit(types.boolean(_RO4, _RO2, _RO2, _W3), cache=True)
def below_gaps(
    a_ends: np.ndarray, a_radius: np.ndarray, cap_z: np.ndarray, out: np.ndarray
) -> bool:
    """Gaps ``out (K, A, B)`` of capsules ``a`` ``(K, A, 2, 3)``, ``(K, A)`` to sets ``b``
    bounded from above at heights ``cap_z (K, B)`` (world z; ``inf``: no bound): a pair whose
    ``a`` capsule lies wholly above ``b``'s bound cannot touch, its gap becomes ``inf``.
    Returns whether any pair may still touch (gap <= 0 or NaN)."""
    touch = False
    for k in range(out.shape[0]):
        for i in range(out.shape[1]):
            lo_z = lowest_z(a_ends[k, i, 0, 2], a_ends[k, i, 1, 2], a_radius[k, i])
            for j in range(out.shape[2]):
                if lo_z > cap_z[k, j]:  # NaN: no bound
                    out[k, i, j] = np.inf
                elif not out[k, i, j] > 0.0:
                    touch = True
    return touch


@njit(cache=True)
def _same_ends(ends: np.ndarray, k: int) -> bool:
    """``ends[k]`` equals ``ends[k - 1]`` exactly (``k >= 1``; NaN never equals)."""
    for i in range(ends.shape[1]):
        for e in range(2):
            for r in range(3):
                if not ends[k, i, e, r] == ends[k - 1, i, e, r]:
                    return False
    return True


@njit(cache=True)
def set_pair_entry(
    ends: np.ndarray,
    radius: np.ndarray,
    k: int,
    ke: int,
    kr: int,
    a: int,
    b: int,
    d: np.ndarray,
    s: np.ndarray,
) -> float:
    """One pair ``a < b`` of :func:`set_pair_distances` on interval ``k`` (capsules ``ends[ke]``,
    ``radius[kr]``): writes ``d[k, a, b] = d[k, b, a]`` and ``s[k, a, b], s[k, b, a]``;
    returns the axis distance. For callers that need only some pairs (the same numbers)."""
    p, q = ends[ke, a], ends[ke, b]
    axis, s[k, a, b], s[k, b, a] = segment_closest(
        p[0, 0], p[0, 1], p[0, 2], p[1, 0], p[1, 1], p[1, 2],
        q[0, 0], q[0, 1], q[0, 2], q[1, 0], q[1, 1], q[1, 2],
    )  # fmt: skip
    g = axis - radius[kr, a] - radius[kr, b]
    d[k, a, b] = g
    d[k, b, a] = g
    return axis


@njit(types.void(_RO4, _RO2, _W3, _W3), cache=True)
def set_pair_distances(ends: np.ndarray, radius: np.ndarray, d: np.ndarray, s: np.ndarray) -> None:
    """All pairs within one capsule set per interval: surface distances ``d (K, N, N)`` and
    closest-point parameters ``s (K, N, N)`` (``s[k, a, b]`` on ``a`` towards ``b``), each
    unordered pair computed once; the diagonal is ``-2 r`` and ``s = 0`` (as
    ``tests/soa_reference.py``'s ``all_pairs`` minus the radii). ``ends (Ke, N, 2, 3)``,
    ``radius (Kr, N)`` with ``Ke, Kr`` in ``{1, K}``. The segment computation is reused from the
    previous interval when its capsule axes are exactly the same (a set whose radii grow). The
    PFL classification calls the per-pair form :func:`set_pair_entry` only where a rule reads a
    pair; this batch form is the tested reference of it and of :func:`set_neighbours`."""
    K, N = d.shape[0], d.shape[1]
    axis = np.empty((N, N))
    for k in range(K):
        ke = k if ends.shape[0] == K else 0
        kr = k if radius.shape[0] == K else 0
        reuse = k > 0 and (ke == 0 or _same_ends(ends, ke))
        for a in range(N):
            d[k, a, a] = 0.0 - radius[kr, a] - radius[kr, a]
            s[k, a, a] = 0.0
            for b in range(a + 1, N):
                if reuse:
                    s[k, a, b] = s[k - 1, a, b]
                    s[k, b, a] = s[k - 1, b, a]
                    g = axis[a, b] - radius[kr, a] - radius[kr, b]
                    d[k, a, b] = g
                    d[k, b, a] = g
                else:
                    axis[a, b] = set_pair_entry(ends, radius, k, ke, kr, a, b, d, s)


gap_block = 8
"""Capsules per block of :func:`set_neighbours`' first broad phase (contiguous parts: a person's
body parts are contiguous in the PFL classification's sets)."""


@njit(cache=True)
def set_gap_scratch(N: int) -> tuple[np.ndarray, np.ndarray]:
    """Scratch of :func:`set_gap_interval` for ``N`` capsules: spheres ``(N + blocks, 4)`` (the
    capsules', then their blocks' of :data:`gap_block`), axis distances ``(N, N)``."""
    return np.empty((N + (N + gap_block - 1) // gap_block, 4)), np.empty((N, N))


@njit(cache=True)
def set_gap_interval(
    ends: np.ndarray,
    radius: np.ndarray,
    k: int,
    K: int,
    prev: tuple[int, int],
    sph: np.ndarray,
    axis: np.ndarray,
) -> tuple[int, int]:
    """Make the scratch of :func:`set_neighbours` (:func:`set_gap_scratch`) ready for interval
    ``k`` of one capsule set (``ends (Ke, N, 2, 3)``, ``radius (Kr, N)``, ``Ke, Kr`` in ``{1,
    K}``): the bounding spheres ``sph`` of the capsules and of each block of :data:`gap_block`
    contiguous capsules (a sphere holding theirs; NaN where one is), and ``axis (N, N)``, the
    pairs' axis distances (-1: not computed yet), kept while the axes stay the same (a set whose
    radii grow). ``prev``: what the last call returned, ``(-1, -1)`` before the first; call it
    for every ``k`` in order (the axes are compared with the previous interval's). Returns the
    interval's ``(ke, kr)``."""
    ke = k if ends.shape[0] == K else 0
    kr = k if radius.shape[0] == K else 0
    if ke != prev[0] or kr != prev[1]:
        N = ends.shape[1]
        bounding_spheres(ends[ke], radius[kr : kr + 1], sph)
        for b in range(sph.shape[0] - N):
            lo, hi = b * gap_block, min(N, (b + 1) * gap_block)
            cx = cy = cz = 0.0
            for i in range(lo, hi):
                cx, cy, cz = cx + sph[i, 0], cy + sph[i, 1], cz + sph[i, 2]
            cx, cy, cz = cx / (hi - lo), cy / (hi - lo), cz / (hi - lo)
            r = 0.0
            for i in range(lo, hi):
                dx, dy, dz = sph[i, 0] - cx, sph[i, 1] - cy, sph[i, 2] - cz
                ri = math.sqrt(dx * dx + dy * dy + dz * dz) + sph[i, 3]
                if r == r and not ri <= r:  # a NaN radius stays: no skip past a NaN capsule
                    r = ri
            sph[N + b, 0], sph[N + b, 1], sph[N + b, 2], sph[N + b, 3] = cx, cy, cz, r
        if ke != prev[0] and not (ke > 0 and _same_ends(ends, ke)):
            axis[:] = -1.0  # not computed for these axes (a NaN axis stays NaN)
    return ke, kr


@njit(cache=True)
def set_neighbours(
    ends: np.ndarray,
    radius: np.ndarray,
    ke: int,
    kr: int,
    a: int,
    mask: np.ndarray,
    sph: np.ndarray,
    axis: np.ndarray,
    label: np.ndarray,
    new: int,
    found: np.ndarray,
    tail: int,
) -> int:
    """The capsules that may touch capsule ``a`` (surface distance ``<= 0`` or NaN) among those
    not labelled yet (``label[m] < 0``) and paired with it (``mask[a, m]``; ``mask, label``
    ``(N, N)``, ``(N,)``), on the interval whose ``(ke, kr)`` :func:`set_gap_interval` made ready
    (``sph, axis``: its scratch): each is labelled ``new`` and appended to ``found`` at
    ``tail``; returns the new tail. A breadth-first search's step (the PFL classification's
    virtual body parts): a labelled capsule is never compared again. Two broad phases, each a
    lower bound of the distance that must exceed :data:`sphere_slack_m` to skip: the bounding
    sphere of a block of :data:`gap_block` capsules, then the capsule's; then the exact
    distance, its axis part kept in ``axis`` (the same numbers as
    :func:`set_pair_distances`)."""
    N = label.shape[0]
    for b in range(sph.shape[0] - N):
        g_block = np.nan  # the block's bound, computed where a pair first needs it
        for m in range(b * gap_block, min(N, (b + 1) * gap_block)):
            if label[m] >= 0 or not mask[a, m]:
                continue
            if g_block != g_block:
                g_block = sphere_gap(sph, a, sph, N + b)
            if g_block > sphere_slack_m:  # every capsule of the block is that far, at least
                break
            i, j = (a, m) if a < m else (m, a)
            if sphere_gap(sph, i, sph, j) > sphere_slack_m:  # NaN goes on to the exact distance
                continue
            if axis[i, j] < 0.0:
                p, q = ends[ke, i], ends[ke, j]
                axis[i, j] = segment_closest(
                    p[0, 0], p[0, 1], p[0, 2], p[1, 0], p[1, 1], p[1, 2],
                    q[0, 0], q[0, 1], q[0, 2], q[1, 0], q[1, 1], q[1, 2],
                )[0]  # fmt: skip
            if not axis[i, j] - radius[kr, i] - radius[kr, j] > 0.0:
                label[m] = new
                found[tail] = m
                tail += 1
    return tail


@njit(cache=True)
def _segment_box(
    p: np.ndarray, q: np.ndarray, R: np.ndarray, c: np.ndarray, h: np.ndarray, work: np.ndarray
) -> tuple[float, float, float, float, float, float, float]:
    """Closest points of segment ``[p, q]`` and one solid box (rotation ``R``, centre ``c``,
    half extents ``h``): ``(distance, segment point xyz, box point xyz)``; ``work (3, 8)``
    scratch. The piecewise minimisation of ``tests/soa_reference.py``'s ``segment_box_soa``."""
    a, d, bp = work[0], work[1], work[2]
    for i in range(3):
        a[i] = R[0, i] * (p[0] - c[0]) + R[1, i] * (p[1] - c[1]) + R[2, i] * (p[2] - c[2])
        b = R[0, i] * (q[0] - c[0]) + R[1, i] * (q[1] - c[1]) + R[2, i] * (q[2] - c[2])
        d[i] = b - a[i]
    bp[0], bp[7] = 0.0, 1.0
    for i in range(3):
        ds = d[i] if abs(d[i]) > 1e-12 else 1e-12
        x = (h[i] - a[i]) / ds
        bp[1 + i] = 0.0 if x < 0.0 else (1.0 if x > 1.0 else x)
        x = (-h[i] - a[i]) / ds
        bp[4 + i] = 0.0 if x < 0.0 else (1.0 if x > 1.0 else x)
    for m in range(1, 8):  # insertion sort (NaN ends up in place: handled below)
        x = bp[m]
        n = m - 1
        while n >= 0 and bp[n] > x:
            bp[n + 1] = bp[n]
            n -= 1
        bp[n + 1] = x
    f_best, s_best = np.inf, 0.0
    for m in range(7):
        lo, hi = bp[m], bp[m + 1]
        mid = 0.5 * (lo + hi)
        qa = qb = 0.0
        for i in range(3):
            x = a[i] + mid * d[i]
            sign = (1.0 if x > h[i] else 0.0) - (1.0 if x < -h[i] else 0.0)
            act = sign * sign
            qa += act * d[i] * d[i]
            qb += act * (a[i] - sign * h[i]) * d[i]
        if qa > 0.0:
            s = -qb / qa
            s = lo if s < lo else (hi if s > hi else s)
        else:
            s = lo
        f = 0.0
        for i in range(3):
            ex = abs(a[i] + s * d[i]) - h[i]
            ex = ex if ex > 0.0 else 0.0
            f += ex * ex
        if f < f_best:
            f_best, s_best = f, s
    x0, x1, x2 = a[0] + s_best * d[0], a[1] + s_best * d[1], a[2] + s_best * d[2]
    b0 = -h[0] if x0 < -h[0] else (h[0] if x0 > h[0] else x0)
    b1 = -h[1] if x1 < -h[1] else (h[1] if x1 > h[1] else x1)
    b2 = -h[2] if x2 < -h[2] else (h[2] if x2 > h[2] else x2)
    return (
        math.sqrt(f_best),
        R[0, 0] * x0 + R[0, 1] * x1 + R[0, 2] * x2 + c[0],
        R[1, 0] * x0 + R[1, 1] * x1 + R[1, 2] * x2 + c[1],
        R[2, 0] * x0 + R[2, 1] * x1 + R[2, 2] * x2 + c[2],
        R[0, 0] * b0 + R[0, 1] * b1 + R[0, 2] * b2 + c[0],
        R[1, 0] * b0 + R[1, 1] * b1 + R[1, 2] * b2 + c[1],
        R[2, 0] * b0 + R[2, 1] * b1 + R[2, 2] * b2 + c[2],
    )


@njit(types.void(_RO4, _RO2, _RO3, _RO2, _W3), cache=True)
def box_axis_gaps(
    ends: np.ndarray,
    radius: np.ndarray,
    T_world_box: np.ndarray,
    half_extents_m: np.ndarray,
    axis: np.ndarray,
) -> None:
    """Axis-to-box distances ``axis (Ke, N, B)`` of capsules ``ends (Ke, N, 2, 3)`` against solid
    boxes ``(B, 4, 4)``, ``(B, 3)``, for a touch test ``axis - radius[k] <= 0`` with radii
    ``radius (Kr, N)`` (any ``Kr``): exact where the capsule may touch the box for some of its
    radii; elsewhere a lower bound (the axis' bounding sphere to the box) that exceeds every
    radius of the capsule by more than :data:`sphere_slack_m`, so the test's answer is the
    exact one. A non-finite capsule gives NaN."""
    Ke, N, B = axis.shape
    work = np.empty((3, 8))
    r_max = np.full(N, -np.inf)
    for kr in range(radius.shape[0]):
        for i in range(N):
            r_max[i] = max(r_max[i], radius[kr, i])  # a NaN radius: its test is true anyway
    for k in range(Ke):
        if k > 0 and _same_ends(ends, k):  # the same axes as the previous interval
            axis[k] = axis[k - 1]
            continue
        for i in range(N):
            p, q = ends[k, i, 0], ends[k, i, 1]
            cx, cy, cz = 0.5 * (p[0] + q[0]), 0.5 * (p[1] + q[1]), 0.5 * (p[2] + q[2])
            hx, hy, hz = 0.5 * (q[0] - p[0]), 0.5 * (q[1] - p[1]), 0.5 * (q[2] - p[2])
            half_len = math.sqrt(hx * hx + hy * hy + hz * hz)
            finite = math.isfinite(cx + cy + cz + half_len)
            for b in range(B):
                if not finite:
                    axis[k, i, b] = np.nan
                    continue
                R, c, h = T_world_box[b, :3, :3], T_world_box[b, :3, 3], half_extents_m[b]
                out2 = 0.0
                for j in range(3):  # centre in the box frame, excess over the half extents
                    x = R[0, j] * (cx - c[0]) + R[1, j] * (cy - c[1]) + R[2, j] * (cz - c[2])
                    ex = abs(x) - h[j]
                    out2 += ex * ex if ex > 0.0 else 0.0
                lower = math.sqrt(out2) - half_len  # distance to a convex set is 1-Lipschitz
                if lower - r_max[i] > sphere_slack_m:
                    axis[k, i, b] = lower
                else:
                    axis[k, i, b] = _segment_box(p, q, R, c, h, work)[0]


@njit(cache=True)
def box_entry(
    ends: np.ndarray,
    radius: np.ndarray,
    T_world_box: np.ndarray,
    half_extents_m: np.ndarray,
    k: int,
    kr: int,
    i: int,
    b: int,
    work: np.ndarray,
    dist: np.ndarray,
    normal: np.ndarray,
    want_normal: bool,
) -> float:
    """One entry ``(k, i, b)`` of :func:`box_distances` (``work (3, 8)`` scratch): writes
    ``dist[k, i, b]`` and, with ``want_normal``, ``normal[k, i, b]``; returns the axis distance
    (NaN for a non-finite capsule). For callers that need only some entries (the same
    numbers)."""
    p, q = ends[k, i, 0], ends[k, i, 1]
    finite = True
    for r in range(3):
        finite = finite and math.isfinite(p[r]) and math.isfinite(q[r])
    if not finite:
        dist[k, i, b] = np.nan
        if want_normal:
            for r in range(3):
                normal[k, i, b, r] = np.nan
        return np.nan
    R, c = T_world_box[b, :3, :3], T_world_box[b, :3, 3]
    res = _segment_box(p, q, R, c, half_extents_m[b], work)
    dist[k, i, b] = res[0] - radius[kr, i]
    if want_normal:
        normal[k, i, b, 0] = res[1] - res[4]
        normal[k, i, b, 1] = res[2] - res[5]
        normal[k, i, b, 2] = res[3] - res[6]
    return res[0]


@njit(types.void(_RO4, _RO2, _RO3, _RO2, _W3, _W4), cache=True)
def box_distances(
    ends: np.ndarray,
    radius: np.ndarray,
    T_world_box: np.ndarray,
    half_extents_m: np.ndarray,
    dist: np.ndarray,
    normal: np.ndarray,
) -> None:
    """Capsules ``ends (K, N, 2, 3)``, ``radius (Kr, N)`` (``Kr`` in ``{1, K}``) against solid
    boxes ``(B, 4, 4)``, ``(B, 3)``: surface distances ``dist (K, N, B)`` and, when ``normal``
    has shape ``(K, N, B, 3)`` (else ``(0, 0, 0, 3)``), the vector from the closest box point to
    the closest segment point (world frame, not normalised). A non-finite capsule gives NaN. The
    PFL classification calls the per-entry form :func:`box_entry` only where a rule reads an
    entry; this batch form is the tested reference of it and of :func:`box_axis_gaps`."""
    K, N, B = dist.shape
    want_normal = normal.shape[0] == K
    work = np.empty((3, 8))
    axis = np.empty((N, B))
    for k in range(K):
        kr = k if radius.shape[0] == K else 0
        if k > 0 and _same_ends(ends, k):  # the same axes as the previous interval
            for i in range(N):
                for b in range(B):
                    dist[k, i, b] = axis[i, b] - radius[kr, i]
                    if want_normal:
                        for r in range(3):
                            normal[k, i, b, r] = normal[k - 1, i, b, r]
            continue
        for i in range(N):
            for b in range(B):
                axis[i, b] = box_entry(
                    ends, radius, T_world_box, half_extents_m, k, kr, i, b, work, dist, normal,
                    want_normal,
                )  # fmt: skip
