"""Batched geometry of capsules, balls and boxes.

Conventions: a capsule set is ``ends`` of shape ``(..., 2, 3)`` (segment end points, metres) and
``radius_m`` of shape ``(...)``; a ball is a capsule whose two ends coincide. Boxes are oriented:
``T_world_box`` of shape ``(..., 4, 4)`` and ``half_extents_m`` of shape ``(..., 3)``.
All functions broadcast over leading axes and never loop in Python over capsules.

Where each runs: these numpy functions serve everything outside the control cycle (fitting link
capsules, volume analysis, the dashboard, the simulator's ground truth, the JSSA study) and are
the oracle of the compiled kernels. The control cycle runs
:mod:`sara_app.geometry.shape_kernels` instead: the same mathematics written as loops, because
at one cycle's sizes numpy spends most of its time in per-call overhead. The containment
analysis's distances run in :mod:`sara_app.human.containment_kernels`, and the Monte-Carlo
volumes count their points in :mod:`sara_app.geometry.volume_kernels` (at a recording's sizes
numpy's temporaries were the cost).
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12
# Segments whose directions have sin^2(angle) below this are handled as parallel. The error of
# the parallel branch is about length * sin(angle) (<= 1e-12 of the segment length here); above
# it, the cross-product form of the closest-point formula is accurate to round-off.
_PARALLEL_SIN2 = 1e-24


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", a, b)


def point_segment_closest(points: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points of segments ``(..., 2, 3)`` to points ``(..., 3)``, broadcast: the
    distance ``(...)`` and the closest point's parameter ``s (...)`` in [0, 1] along each
    segment (0 for a point segment)."""
    p0, p1 = ends[..., 0, :], ends[..., 1, :]
    d = p1 - p0
    dd = _dot(d, d)
    # Only an exactly degenerate segment is a point; a short one is still projected onto (a
    # clamp such as max(dd, eps) would leave s short of the true parameter by up to its length).
    s = np.clip(_dot(points - p0, d) / np.where(dd > 0.0, dd, 1.0), 0.0, 1.0)
    closest = p0 + s[..., None] * d
    return np.linalg.norm(points - closest, axis=-1), s


def point_segment_distance(points: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Distance from points ``(..., 3)`` to segments ``(..., 2, 3)``, broadcast: ``(...)``."""
    return point_segment_closest(points, ends)[0]


def segment_segment_closest(
    ends_a: np.ndarray, ends_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of segment pairs, broadcast over leading axes.

    Returns ``(distance, s, t)``: distance ``(...)`` and the parameters in [0, 1] of the closest
    points on a and b. Handles degenerate (point) segments and parallel segments.
    """
    p1, q1 = ends_a[..., 0, :], ends_a[..., 1, :]
    p2, q2 = ends_b[..., 0, :], ends_b[..., 1, :]
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = _dot(d1, d1), _dot(d2, d2)
    b, c, f = _dot(d1, d2), _dot(d1, r), _dot(d2, r)
    # Only exactly degenerate segments are points: treating a short segment as its first end
    # overestimates the distance by up to its length.
    a_pos, e_pos = a > 0.0, e > 0.0
    a_safe, e_safe = np.where(a_pos, a, 1.0), np.where(e_pos, e, 1.0)
    # a e - b^2 = |d1 x d2|^2 and b f - c e = (d1 x d2) . (d2 x r) (Lagrange identity). The cross
    # products avoid the cancellation of a e - b^2 for nearly parallel segments.
    n = np.cross(d1, d2)
    denom = _dot(n, n)
    # Parallel (or degenerate) pairs: any s is optimal for the infinite lines; take s = 0 and
    # let the clamping below find the best t and then the best s.
    general = denom > _PARALLEL_SIN2 * a * e
    s = np.where(general, _dot(n, np.cross(d2, r)) / np.where(general, denom, 1.0), 0.0)
    s = np.clip(np.where(a_pos, s, 0.0), 0.0, 1.0)
    # A point segment b (e = 0): t = -1 sends it through the clamp branch, s = clip(-c / a).
    t = np.where(e_pos, (b * s + f) / e_safe, -1.0)
    # t outside [0, 1]: clamp it and recompute s for the clamped t.
    t_clamped = np.clip(t, 0.0, 1.0)
    s = np.where(
        t != t_clamped,
        np.where(a_pos, np.clip((b * t_clamped - c) / a_safe, 0.0, 1.0), 0.0),
        s,
    )
    t = t_clamped
    c1 = p1 + s[..., None] * d1
    c2 = p2 + t[..., None] * d2
    return np.linalg.norm(c1 - c2, axis=-1), s, t


def segment_segment_distance(ends_a: np.ndarray, ends_b: np.ndarray) -> np.ndarray:
    """Distance between segments ``(..., 2, 3)`` and ``(..., 2, 3)``, broadcast: ``(...)``."""
    return segment_segment_closest(ends_a, ends_b)[0]


def segment_pair_distances(ends_a: np.ndarray, ends_b: np.ndarray) -> np.ndarray:
    """Distances of paired segments ``(N, 2, 3)`` and ``(N, 2, 3)`` -> ``(N,)``.

    The arithmetic of :func:`segment_segment_closest` on flat component arrays (no broadcasting,
    no ``einsum``/``cross`` dispatch): the hot-path version for the shield's exact checks, about
    three times faster for a few hundred pairs. Tested equal to the general function.
    """
    a0 = ends_a[:, 0, :].T
    b0 = ends_b[:, 0, :].T
    d1 = ends_a[:, 1, :].T - a0  # (3, N) component rows
    d2 = ends_b[:, 1, :].T - b0
    r = a0 - b0
    a = (d1 * d1).sum(0)
    e = (d2 * d2).sum(0)
    b = (d1 * d2).sum(0)
    c = (d1 * r).sum(0)
    f = (d2 * r).sum(0)
    a_pos, e_pos = a > 0.0, e > 0.0
    a_safe, e_safe = np.where(a_pos, a, 1.0), np.where(e_pos, e, 1.0)
    nx = d1[1] * d2[2] - d1[2] * d2[1]
    ny = d1[2] * d2[0] - d1[0] * d2[2]
    nz = d1[0] * d2[1] - d1[1] * d2[0]
    mx = d2[1] * r[2] - d2[2] * r[1]
    my = d2[2] * r[0] - d2[0] * r[2]
    mz = d2[0] * r[1] - d2[1] * r[0]
    denom = nx * nx + ny * ny + nz * nz
    general = denom > _PARALLEL_SIN2 * a * e
    s = np.where(general, (nx * mx + ny * my + nz * mz) / np.where(general, denom, 1.0), 0.0)
    s = np.clip(np.where(a_pos, s, 0.0), 0.0, 1.0)
    t = np.where(e_pos, (b * s + f) / e_safe, -1.0)
    t_clamped = np.clip(t, 0.0, 1.0)
    s = np.where(
        t != t_clamped,
        np.where(a_pos, np.clip((b * t_clamped - c) / a_safe, 0.0, 1.0), 0.0),
        s,
    )
    g = r + d1 * s - d2 * t_clamped
    return np.sqrt((g * g).sum(0))


def capsule_distances(
    ends_a: np.ndarray, radius_a: np.ndarray, ends_b: np.ndarray, radius_b: np.ndarray
) -> np.ndarray:
    """Surface distances of all pairs: a ``(N, 2, 3), (N,)`` vs b ``(M, 2, 3), (M,)`` -> ``(N, M)``.

    Negative values mean penetration (the value is then a lower bound of minus the depth).
    """
    axis = segment_segment_distance(ends_a[:, None], ends_b[None, :])
    return axis - radius_a[:, None] - radius_b[None, :]


def capsules_intersect(
    ends_a: np.ndarray, radius_a: np.ndarray, ends_b: np.ndarray, radius_b: np.ndarray
) -> np.ndarray:
    """``(N, M)`` bool: capsule i of a and capsule j of b share at least one point."""
    return capsule_distances(ends_a, radius_a, ends_b, radius_b) <= 0.0


def points_in_capsules(points: np.ndarray, ends: np.ndarray, radius_m: np.ndarray) -> np.ndarray:
    """Whether each point ``(..., 3)`` lies in its capsule ``(..., 2, 3), (...)``, broadcast."""
    return point_segment_distance(points, ends) <= radius_m


def points_in_union(points: np.ndarray, ends: np.ndarray, radius_m: np.ndarray) -> np.ndarray:
    """``(S,)`` bool: point s ``(S, 3)`` lies in at least one capsule ``(N, 2, 3), (N,)``."""
    d = point_segment_distance(points[:, None, :], ends[None, :, :, :])
    return np.any(d <= radius_m[None, :], axis=1)


def ball_enclosing_balls(
    c1: np.ndarray, r1: np.ndarray, c2: np.ndarray, r2: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Smallest ball enclosing two balls ``(..., 3), (...)`` each; returns ``(centre, radius)``."""
    d = np.linalg.norm(c2 - c1, axis=-1)
    radius = np.maximum(np.maximum(r1, r2), 0.5 * (d + r1 + r2))
    # The centre lies on the line c1 -> c2 at distance radius - r1 from c1 (when not nested).
    w = np.where(d > _EPS, np.clip((radius - r1) / np.maximum(d, _EPS), 0.0, 1.0), 0.0)
    w = np.where(r1 >= d + r2, 0.0, np.where(r2 >= d + r1, 1.0, w))
    return c1 + w[..., None] * (c2 - c1), radius


def capsule_enclosing_capsules(
    ends_a: np.ndarray, radius_a: np.ndarray, ends_b: np.ndarray, radius_b: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """A capsule enclosing two capsules with corresponding ends, e.g. one link at t_a and t_b.

    The axis runs between the midpoints of corresponding ends; the radius grows by half the
    larger end displacement. Sound for any pair (a point at axis parameter s of either capsule is
    within that bound of the new axis at s). Returns ``(ends (..., 2, 3), radius (...))``.
    """
    mid = 0.5 * (ends_a + ends_b)
    half_shift = 0.5 * np.linalg.norm(ends_a - ends_b, axis=-1).max(axis=-1)
    return mid, np.maximum(radius_a, radius_b) + half_shift


def capsule_volume(ends: np.ndarray, radius_m: np.ndarray) -> np.ndarray:
    """Volume of each capsule, ``(...)``: cylinder plus one ball."""
    length = np.linalg.norm(ends[..., 1, :] - ends[..., 0, :], axis=-1)
    return np.pi * radius_m**2 * length + 4.0 / 3.0 * np.pi * radius_m**3


def union_volume_mc(
    ends: np.ndarray, radius_m: np.ndarray, n_samples: int, rng: np.random.Generator
) -> tuple[float, float]:
    """Monte-Carlo volume of a union of capsules ``(N, 2, 3), (N,)``: ``(volume, std_error)``.
    The points are counted by :func:`~sara_app.geometry.volume_kernels.union_count`
    (:func:`points_in_union` is its oracle)."""
    from sara_app.geometry.volume_kernels import union_count
    from sara_app.kernel_types import as_f8

    lo = (ends.min(axis=1) - radius_m[:, None]).min(axis=0)
    hi = (ends.max(axis=1) + radius_m[:, None]).max(axis=0)
    box_volume = float(np.prod(hi - lo))
    pts = lo + rng.random((n_samples, 3)) * (hi - lo)
    share = union_count(pts, as_f8(ends), as_f8(radius_m)) / n_samples
    return box_volume * share, box_volume * float(np.sqrt(share * (1 - share) / n_samples))


def effective_volume_mc(
    sets: list[tuple[np.ndarray, np.ndarray]],
    part_maps: list[np.ndarray],
    n_samples: int,
    rng: np.random.Generator,
) -> tuple[float, float]:
    """Monte-Carlo volume of the per-body-part intersection of several models' capsule sets
    (the set the per-part verdict effectively uses): the union over body parts ``p`` of the
    intersection over models ``m`` of capsule ``part_maps[m][p]`` of ``sets[m] = (ends (C_m,
    2, 3), radius (C_m,))``. Returns ``(volume, std_error)``. The points are counted by
    :func:`~sara_app.geometry.volume_kernels.effective_count`."""
    from sara_app.geometry.volume_kernels import effective_count
    from sara_app.kernel_types import as_f8

    lo = np.full(3, -np.inf)
    hi = np.full(3, np.inf)
    for ends, radius in sets:  # the effective set lies in every model's union: the boxes meet
        lo = np.maximum(lo, (ends.min(axis=1) - radius[:, None]).min(axis=0))
        hi = np.minimum(hi, (ends.max(axis=1) + radius[:, None]).max(axis=0))
    if not np.all(hi > lo):
        return 0.0, 0.0
    box_volume = float(np.prod(hi - lo))
    pts = lo + rng.random((n_samples, 3)) * (hi - lo)
    # each model's capsule of each part: (M, P, 2, 3), (M, P)
    caps_ends = np.stack([as_f8(ends)[pm] for (ends, _), pm in zip(sets, part_maps)])
    caps_r = np.stack([as_f8(radius)[pm] for (_, radius), pm in zip(sets, part_maps)])
    share = effective_count(pts, caps_ends, caps_r) / n_samples
    return box_volume * share, box_volume * float(np.sqrt(share * (1 - share) / n_samples))


def transform_points(T_a_b: np.ndarray, points_b: np.ndarray) -> np.ndarray:
    """Apply homogeneous transforms ``(..., 4, 4)`` to points ``(..., 3)``, broadcast."""
    return np.einsum("...ij,...j->...i", T_a_b[..., :3, :3], points_b) + T_a_b[..., :3, 3]


def point_box_distance(
    points: np.ndarray, T_world_box: np.ndarray, half_extents_m: np.ndarray
) -> np.ndarray:
    """Distance from points ``(..., 3)`` to solid oriented boxes, broadcast; 0 inside."""
    R, p = T_world_box[..., :3, :3], T_world_box[..., :3, 3]
    local = np.einsum("...ji,...j->...i", R, points - p)
    excess = np.maximum(np.abs(local) - half_extents_m, 0.0)
    return np.linalg.norm(excess, axis=-1)


def segment_box_distance(
    ends: np.ndarray, T_world_box: np.ndarray, half_extents_m: np.ndarray
) -> np.ndarray:
    """Exact distance between segments ``(..., 2, 3)`` and solid oriented boxes, broadcast.

    In the box frame the squared distance along the segment, f(s) = sum_i max(|x_i(s)| - h_i, 0)^2,
    is convex and piecewise quadratic with breakpoints where x_i(s) = +-h_i. Each piece is
    minimised in closed form; the minimum over the pieces is exact.
    """
    R, p = T_world_box[..., :3, :3], T_world_box[..., :3, 3]
    a = np.einsum("...ji,...j->...i", R, ends[..., 0, :] - p)  # (..., 3) in box frame
    b = np.einsum("...ji,...j->...i", R, ends[..., 1, :] - p)
    shape = np.broadcast_shapes(a.shape, np.shape(half_extents_m))
    a, b, h = (np.broadcast_to(v, shape) for v in (a, b, half_extents_m))
    d = b - a
    d_safe = np.where(np.abs(d) > _EPS, d, _EPS)
    # Breakpoints s where a_i + s d_i = +-h_i, plus 0 and 1: (..., 8), sorted.
    bp = np.concatenate(
        [
            np.zeros(a.shape[:-1] + (1,)),
            np.clip((h - a) / d_safe, 0.0, 1.0),
            np.clip((-h - a) / d_safe, 0.0, 1.0),
            np.ones(a.shape[:-1] + (1,)),
        ],
        axis=-1,
    )
    bp.sort(axis=-1)
    lo, hi = bp[..., :-1], bp[..., 1:]  # (..., 7) pieces
    mid = 0.5 * (lo + hi)
    x_mid = a[..., None, :] + mid[..., None] * d[..., None, :]  # (..., 7, 3)
    # On a piece each coordinate is either inside its slab (no cost), above (+h) or below (-h).
    sign = np.where(x_mid > h[..., None, :], 1.0, np.where(x_mid < -h[..., None, :], -1.0, 0.0))
    # f(s) = sum_i sign_i^2 (a_i + s d_i - sign_i h_i)^2 ; minimise over s in [lo, hi].
    off = a[..., None, :] - sign * h[..., None, :]
    act = sign * sign
    qa = np.sum(act * d[..., None, :] ** 2, axis=-1)
    qb = np.sum(act * off * d[..., None, :], axis=-1)
    # qa = 0 only where f is constant on the piece; a tiny qa still has an interior minimum.
    s_star = np.where(qa > 0.0, np.clip(-qb / np.where(qa > 0.0, qa, 1.0), lo, hi), lo)
    x = a[..., None, :] + s_star[..., None] * d[..., None, :]
    excess = np.maximum(np.abs(x) - h[..., None, :], 0.0)
    return np.sqrt(np.min(np.sum(excess**2, axis=-1), axis=-1))


def capsule_box_distances(
    ends: np.ndarray, radius_m: np.ndarray, T_world_box: np.ndarray, half_extents_m: np.ndarray
) -> np.ndarray:
    """Surface distances of capsules ``(N, 2, 3), (N,)`` to boxes ``(B, 4, 4), (B, 3)``.

    Returns ``(N, B)``.
    """
    axis = segment_box_distance(ends[:, None], T_world_box[None], half_extents_m[None])
    return axis - radius_m[:, None]


_Z = np.array([0.0, 0.0, 1.0])


def quat_z_to(d: np.ndarray) -> np.ndarray:
    """Quaternions ``(N, 4)`` (w, x, y, z) of the shortest rotations taking +z onto ``d (N, 3)``.

    Half-vector form: ``h = (z + d) / |z + d|``, ``q = (z . h, z x h)``; ``d = -z`` gives a half
    turn about x. Near ``-z`` the component ``1 + d_z`` is taken as ``(d_x^2 + d_y^2) / (1 -
    d_z)`` (the same for a unit ``d``): computed as ``1 + d_z`` it cancels to a few ulps and the
    tube of a long capsule pointing almost straight down was off by ~1e-9 relative (found by the
    property test).
    """
    h = d + _Z
    down = d[:, 2] < 0.0
    side2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]
    h[:, 2] = np.where(down, side2 / np.where(down, 1.0 - d[:, 2], 1.0), h[:, 2])
    m = np.max(np.abs(h), axis=1)
    flip = m < 1e-200  # d = -z (to rounding): no direction to turn through
    # scaled by the largest component first: the squares of components near 1e-161 are
    # subnormal and their norm was off by 0.5 % (found by the property test)
    h = h / np.where(flip, 1.0, m)[:, None]
    h = h / np.where(flip, 1.0, np.linalg.norm(h, axis=1))[:, None]
    q = np.zeros((d.shape[0], 4))
    q[:, 0] = h[:, 2]
    q[:, 1] = -h[:, 1]
    q[:, 2] = h[:, 0]
    q[flip] = (0.0, 1.0, 0.0, 0.0)
    return q


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors ``v (..., 3)`` by unit quaternions ``q (..., 4)`` (w, x, y, z)."""
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)
