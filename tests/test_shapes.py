"""Property tests of ``sara_app.geometry.shapes`` against brute-force and independent references.

Every distance function is checked two ways:

* against a dense grid on the segment(s): the grid minimum is attained by actual points, so the
  function must never exceed it (up to float round-off), and the true minimum lies within the
  grid's resolution bound ``step / 2 * (segment lengths)`` below it;
* against an independent sharp reference where one exists (the distance from a segment point to
  a convex set is convex in the segment parameter, so a ternary search finds its minimum).

Inputs deliberately include degenerate segments (points), parallel, anti-parallel, collinear
overlapping, nearly parallel, very short and very long segments, degenerate and randomly rotated
boxes.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, example, given, settings
from hypothesis import strategies as st

from sara_app.geometry import shapes as geo

# ----------------------------------------------------------------------------------------------
# Settings and tolerances

MC = settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
FAST = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
MEDIUM = settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
MANY = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

GRID_2D = 121  # samples per segment for segment-vs-segment grids (121 x 121 pairs)
GRID_1D = 2001  # samples per segment for point / box references


def tol(*arrays: np.ndarray) -> float:
    """Round-off allowance: 1e-9 relative to the coordinate scale of the inputs (metres)."""
    scale = max([1.0] + [float(np.max(np.abs(a))) for a in arrays if np.size(a)])
    return 1e-9 * scale


# ----------------------------------------------------------------------------------------------
# Independent references (plain numpy, written without looking at the implementation's tricks)


def seg_points(ends: np.ndarray, n: int) -> np.ndarray:
    s = np.linspace(0.0, 1.0, n)
    return ends[0] + s[:, None] * (ends[1] - ends[0])


def seg_len(ends: np.ndarray) -> float:
    return float(np.linalg.norm(ends[1] - ends[0]))


def ref_point_segment(x: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Exact distance of points ``(K, 3)`` (or ``(3,)``) to one segment by projection."""
    p, q = ends
    d = q - p
    dd = float(d @ d)
    if dd == 0.0:
        return np.linalg.norm(x - p, axis=-1)
    s = np.clip(((x - p) @ d) / dd, 0.0, 1.0)
    return np.linalg.norm(x - (p + np.multiply.outer(s, d)), axis=-1)


def grid_point_segment(x: np.ndarray, ends: np.ndarray) -> tuple[float, float]:
    """Brute force: (min distance over a dense grid of the segment, resolution bound)."""
    pts = seg_points(ends, GRID_1D)
    return float(np.min(np.linalg.norm(pts - x, axis=-1))), seg_len(ends) / (2 * (GRID_1D - 1))


def grid_segment_segment(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Brute force over a ``GRID_2D`` x ``GRID_2D`` grid: (min distance, resolution bound)."""
    pa, pb = seg_points(a, GRID_2D), seg_points(b, GRID_2D)
    dmin = float(np.min(np.linalg.norm(pa[:, None, :] - pb[None, :, :], axis=-1)))
    return dmin, (seg_len(a) + seg_len(b)) / (2 * (GRID_2D - 1))


def ternary_min(fun, iters: int = 90) -> float:
    """Minimum of a convex function on [0, 1] (value only), by ternary search."""
    lo, hi = 0.0, 1.0
    for _ in range(iters):
        m1, m2 = lo + (hi - lo) / 3.0, hi - (hi - lo) / 3.0
        if fun(m1) <= fun(m2):
            hi = m2
        else:
            lo = m1
    return min(fun(lo), fun(hi), fun(0.0), fun(1.0))


def sharp_segment_segment(a: np.ndarray, b: np.ndarray) -> float:
    """s -> dist(a(s), segment b) is convex, so ternary search gives the exact minimum."""
    d = a[1] - a[0]
    return ternary_min(lambda s: float(ref_point_segment(a[0] + s * d, b)))


def quat_to_rot(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def ref_point_box(x: np.ndarray, T: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Distance of points ``(K, 3)`` to a solid box: clamp in the box frame, map back, measure."""
    R, p = T[:3, :3], T[:3, 3]
    local = (x - p) @ R  # rows: R^T (x - p)
    closest_world = np.clip(local, -h, h) @ R.T + p
    return np.linalg.norm(x - closest_world, axis=-1)


def box_samples(T: np.ndarray, h: np.ndarray, rng: np.random.Generator, n: int) -> np.ndarray:
    """Points of the solid box: random interior points, face points and the 8 corners."""
    u = rng.uniform(-1.0, 1.0, (n, 3))
    face = u.copy()
    axis = rng.integers(0, 3, n)
    face[np.arange(n), axis] = np.sign(face[np.arange(n), axis]) + (face[np.arange(n), axis] == 0)
    corners = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], float)
    local = np.concatenate([u, face, corners]) * h
    return local @ T[:3, :3].T + T[:3, 3]


def random_unit(rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    v = rng.normal(size=(3,) if n is None else (n, 3))
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ----------------------------------------------------------------------------------------------
# Strategies

coord = st.floats(-3.0, 3.0, allow_nan=False, allow_infinity=False)
vec3 = st.builds(lambda x, y, z: np.array([x, y, z]), coord, coord, coord)
unit3 = vec3.filter(lambda v: np.linalg.norm(v) > 1e-2).map(lambda v: v / np.linalg.norm(v))
seeds = st.integers(0, 2**32 - 1)
radii = st.one_of(st.just(0.0), st.floats(1e-3, 1.5))

SEG_KINDS = ["generic", "generic", "point", "short", "long"]


@st.composite
def segments(draw, kind: str | None = None) -> np.ndarray:
    kind = kind or draw(st.sampled_from(SEG_KINDS))
    p = draw(vec3)
    if kind == "generic":
        q = draw(vec3)
    elif kind == "point":
        q = p.copy()
    elif kind == "short":
        q = p + 10.0 ** draw(st.floats(-9.0, -3.0)) * draw(unit3)
    else:  # long
        q = p + draw(st.floats(10.0, 300.0)) * draw(unit3)
    return np.stack([p, q])


PAIR_KINDS = [
    "independent",
    "a_point",
    "b_point",
    "both_points",
    "same_point",
    "parallel",
    "antiparallel",
    "collinear",
    "identical",
    "nearly_parallel",
    "crossing",
    "short_short",
    "long_long",
]


@st.composite
def segment_pairs(draw, kinds: list[str] = PAIR_KINDS) -> tuple[np.ndarray, np.ndarray]:
    kind = draw(st.sampled_from(kinds))
    if kind == "independent":
        a, b = draw(segments()), draw(segments())
    elif kind == "a_point":
        a, b = draw(segments("point")), draw(segments())
    elif kind == "b_point":
        a, b = draw(segments()), draw(segments("point"))
    elif kind == "both_points":
        a, b = draw(segments("point")), draw(segments("point"))
    elif kind == "same_point":
        a = draw(segments("point"))
        b = a.copy()
    elif kind == "short_short":
        a, b = draw(segments("short")), draw(segments("short"))
        if draw(st.booleans()):  # bring them close together
            b = b - b[0] + a[0] + 1e-6 * draw(vec3)
    elif kind == "long_long":
        a, b = draw(segments("long")), draw(segments("long"))
    else:
        a = draw(segments(draw(st.sampled_from(["generic", "generic", "short", "long"]))))
        p, q = a
        d = q - p
        if kind in ("parallel", "antiparallel"):
            offset = draw(vec3) * draw(st.sampled_from([1.0, 1e-3, 0.0]))
            k = draw(st.floats(0.05, 3.0)) * (1.0 if kind == "parallel" else -1.0)
            c = p + draw(st.floats(-2.0, 2.0)) * d + offset
            b = np.stack([c, c + k * d])
        elif kind == "collinear":
            t0, t1 = draw(st.floats(-1.5, 2.5)), draw(st.floats(-1.5, 2.5))
            b = np.stack([p + t0 * d, p + t1 * d])
        elif kind == "identical":
            b = a.copy() if draw(st.booleans()) else a[::-1].copy()
        elif kind == "nearly_parallel":
            n = max(float(np.linalg.norm(d)), 1e-3)
            e = d + 10.0 ** draw(st.floats(-10.0, -2.0)) * n * draw(unit3)
            e = e * draw(st.sampled_from([1.0, -1.0, 0.5, 2.0]))
            offset = draw(vec3) * draw(st.sampled_from([1.0, 1e-2, 1e-6, 0.0]))
            c = p + draw(st.floats(-1.0, 1.0)) * d + offset
            # c anywhere on b: with w strictly inside (0, 1) the segments can cross at a tiny
            # angle in the middle of both, where no end point is near the closest pair.
            w = draw(st.one_of(st.sampled_from([0.0, 0.5, 1.0]), st.floats(0.0, 1.0)))
            b = np.stack([c - w * e, c + (1.0 - w) * e])
        else:  # crossing: b passes through a point of a (distance 0)
            x = p + draw(st.floats(0.0, 1.0)) * d
            e = draw(unit3) * draw(st.floats(1e-3, 5.0))
            u = draw(st.floats(0.0, 1.0))
            b = np.stack([x - u * e, x + (1.0 - u) * e])
    if draw(st.booleans()):
        a = a[::-1].copy()
    if draw(st.booleans()):
        b = b[::-1].copy()
    return a, b


@st.composite
def capsules(draw, radius=radii) -> tuple[np.ndarray, float]:
    return draw(segments()), draw(radius)


def stack_capsules(caps: list[tuple[np.ndarray, float]]) -> tuple[np.ndarray, np.ndarray]:
    return np.stack([c[0] for c in caps]), np.array([c[1] for c in caps], dtype=float)


@st.composite
def rotations(draw) -> np.ndarray:
    kind = draw(st.sampled_from(["random", "random", "identity", "axis_perm"]))
    if kind == "identity":
        return np.eye(3)
    if kind == "axis_perm":  # exact 90-degree rotations: zeros in R, faces parallel to axes
        perm = draw(st.permutations([0, 1, 2]))
        signs = np.array(draw(st.tuples(*[st.sampled_from([-1.0, 1.0])] * 3)))
        R = np.eye(3)[list(perm)] * signs[:, None]
        return R * np.linalg.det(R)  # make it proper
    q = np.array(draw(st.tuples(*[st.floats(-1.0, 1.0)] * 4)))
    assume(np.linalg.norm(q) > 1e-2)
    return quat_to_rot(q)


half_extent = st.one_of(st.just(0.0), st.floats(1e-3, 2.0))


@st.composite
def boxes(draw) -> tuple[np.ndarray, np.ndarray]:
    T = np.eye(4)
    T[:3, :3] = draw(rotations())
    T[:3, 3] = draw(vec3)
    h = np.array(draw(st.tuples(half_extent, half_extent, half_extent)))
    return T, h


@st.composite
def box_segments(draw, T: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Segments relative to a box, including through it, inside it and parallel to a face."""
    kind = draw(
        st.sampled_from(
            ["free", "through", "inside", "face_parallel", "point", "long", "tiny_near_corner"]
        )
    )
    R, p = T[:3, :3], T[:3, 3]
    if kind == "tiny_near_corner":  # sub-micrometre segment just outside a corner or edge
        signs = np.array(draw(st.tuples(*[st.sampled_from([-1.0, 1.0])] * 3)))
        corner = signs * h
        scale = 10.0 ** draw(st.floats(-8.0, -5.5))
        rel = np.array(draw(st.tuples(*[st.floats(-1.0, 2.0)] * 6))).reshape(2, 3)
        local = corner + scale * rel * signs  # positive rel: outside along that axis
        return local @ R.T + p
    if kind == "free":
        return draw(segments())
    if kind == "point":
        return draw(segments("point"))
    if kind == "long":
        return draw(segments("long"))
    if kind == "face_parallel":
        axis = draw(st.integers(0, 2))
        level = (h[axis] + draw(st.sampled_from([0.0, 1e-6, 0.3]))) * draw(
            st.sampled_from([1.0, -1.0])
        )
        local = np.stack([draw(vec3), draw(vec3)])
        local[:, axis] = level
        return local @ R.T + p
    u = np.array(draw(st.tuples(*[st.floats(-1.0, 1.0)] * 3)))
    x = p + R @ (u * h)  # a point of the solid box
    if kind == "inside":
        v = np.array(draw(st.tuples(*[st.floats(-1.0, 1.0)] * 3)))
        return np.stack([x, p + R @ (v * h)])
    e = draw(unit3) * draw(st.floats(1e-3, 6.0))
    w = draw(st.floats(0.0, 1.0))
    return np.stack([x - w * e, x + (1.0 - w) * e])


# ----------------------------------------------------------------------------------------------
# Segment / segment


@MANY
@given(segment_pairs())
def test_segment_segment_distance_vs_brute_force(pair):
    a, b = pair
    eps = tol(a, b)
    d = float(geo.segment_segment_distance(a, b))
    grid, res = grid_segment_segment(a, b)
    assert d >= 0.0
    assert d <= grid + eps, f"exceeds grid minimum {grid}"  # never larger than a sampled pair
    assert d >= grid - res - eps, f"below grid minimum {grid} minus resolution {res}"
    # Endpoint-to-segment distances are attained by actual point pairs: upper bounds too.
    for x, seg in ((a[0], b), (a[1], b), (b[0], a), (b[1], a)):
        assert d <= float(ref_point_segment(x, seg)) + eps
    # Sharp check against the convex 1-D reference.
    sharp = sharp_segment_segment(a, b)
    assert abs(d - sharp) <= eps, (d, sharp)


@MANY
@given(segment_pairs())
def test_segment_segment_closest_consistent(pair):
    a, b = pair
    eps = tol(a, b)
    d, s, t = (float(v) for v in geo.segment_segment_closest(a, b))
    assert 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0
    ca = a[0] + s * (a[1] - a[0])
    cb = b[0] + t * (b[1] - b[0])
    assert abs(d - float(np.linalg.norm(ca - cb))) <= eps
    assert d == float(geo.segment_segment_distance(a, b))


@MANY
@given(segment_pairs())
def test_segment_segment_symmetric(pair):
    a, b = pair
    eps = tol(a, b)
    d_ab, s_ab, t_ab = geo.segment_segment_closest(a, b)
    d_ba, s_ba, t_ba = geo.segment_segment_closest(b, a)
    assert abs(float(d_ab) - float(d_ba)) <= eps
    # Reversing a segment's direction does not change the distance either.
    assert abs(float(d_ab) - float(geo.segment_segment_distance(a[::-1], b))) <= eps
    assert abs(float(d_ab) - float(geo.segment_segment_distance(a, b[::-1]))) <= eps


@FAST
@given(st.data(), st.sampled_from(["crossing", "identical", "same_point", "collinear"]))
def test_segment_segment_exact_by_construction(data, kind):
    """Touching pairs are at distance 0; collinear ones at the gap between their intervals."""
    a, b = data.draw(segment_pairs([kind]))
    eps = tol(a, b)
    d = float(geo.segment_segment_distance(a, b))
    expected = 0.0
    if kind == "collinear":
        direction = a[1] - a[0]
        length2 = float(direction @ direction)
        if length2 > 0.0:  # parameters of b's ends on a's line (a may be reversed: any order)
            t = (b - a[0]) @ direction / length2
            gap = max(0.0, float(t.min()) - 1.0, -float(t.max()))
            expected = gap * math.sqrt(length2)
        else:  # a is a point, so b is that same point
            expected = 0.0
    assert abs(d - expected) <= eps, (d, expected)


def test_segment_segment_known_values():
    a = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    cases = {
        # parallel, overlapping in projection
        (0.5, 1.0, 0.0, 2.0, 1.0, 0.0): 1.0,
        # parallel, disjoint in projection: corner to corner
        (2.0, 1.0, 0.0, 3.0, 1.0, 0.0): math.sqrt(2.0),
        # anti-parallel, disjoint
        (3.0, 1.0, 0.0, 2.0, 1.0, 0.0): math.sqrt(2.0),
        # collinear, overlapping
        (0.5, 0.0, 0.0, 3.0, 0.0, 0.0): 0.0,
        # collinear, disjoint
        (-3.0, 0.0, 0.0, -1.0, 0.0, 0.0): 1.0,
        # skew, crossing above
        (0.5, -1.0, 2.0, 0.5, 1.0, 2.0): 2.0,
        # point above the middle
        (0.5, 0.0, 3.0, 0.5, 0.0, 3.0): 3.0,
        # point beyond the end
        (4.0, 4.0, 0.0, 4.0, 4.0, 0.0): 5.0,
    }
    for coords, expected in cases.items():
        b = np.array(coords).reshape(2, 3)
        assert abs(float(geo.segment_segment_distance(a, b)) - expected) <= 1e-12, coords
        assert abs(float(geo.segment_segment_distance(b, a)) - expected) <= 1e-12, coords
    p = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    q = np.array([[1.0, 2.0, 5.0], [1.0, 2.0, 5.0]])
    d, s, t = geo.segment_segment_closest(p, q)
    assert float(d) == 2.0 and 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0


@MEDIUM
@given(
    st.floats(-1.0, 2.5),  # log10 of the length of a
    st.floats(-13.0, -3.0),  # log10 of the angle between a and b
    st.floats(0.0, 1.0),  # where b crosses the line of a
    st.floats(0.0, 1.0),  # where on b the crossing lies
    st.floats(0.2, 3.0),  # length of b relative to a
    st.sampled_from([0.0, 1e-9, 1e-6, 1e-3]),  # offset along the common normal
    rotations(),
    vec3,
)
def test_nearly_parallel_segments_vs_sharp_reference(
    log_len, log_angle, u, w, rel, normal_offset, R, shift
):
    """Nearly parallel segments crossing (or passing) at interior points of both: no end point
    is near the closest pair, so a parallel-branch shortcut would show here."""
    length, angle = 10.0**log_len, 10.0**log_angle
    a = np.array([[0.0, 0.0, 0.0], [length, 0.0, 0.0]])
    direction = np.array([math.cos(angle), math.sin(angle), 0.0]) * rel * length
    c = np.array([u * length, 0.0, normal_offset])
    b = np.stack([c - w * direction, c + (1.0 - w) * direction])
    a, b = a @ R.T + shift, b @ R.T + shift
    eps = tol(a, b)
    d = float(geo.segment_segment_distance(a, b))
    sharp = sharp_segment_segment(a, b)
    assert d <= sharp + eps, (d, sharp)
    assert abs(d - sharp) <= eps, (d, sharp)
    grid, res = grid_segment_segment(a, b)
    assert grid - res - eps <= d <= grid + eps


@pytest.mark.parametrize("length", [1.0, 10.0, 300.0])
@pytest.mark.parametrize("angle", [1e-4, 1e-6, 1e-7, 1e-9, 1e-11])
def test_nearly_parallel_segments_crossing_in_the_middle(length, angle):
    """Regression: these were treated as parallel (sin^2 <= 1e-12 relative) and the parallel
    branch (s = 0) reported length * angle / 2 instead of 0 (15 um at 300 m and 1e-7 rad)."""
    a = np.array([[0.0, 0.0, 0.0], [length, 0.0, 0.0]])
    c = np.array([length / 2, 0.0, 0.0])
    u = np.array([math.cos(angle), math.sin(angle), 0.0])
    b = np.stack([c - 0.5 * length * u, c + 0.5 * length * u])
    for x, y in ((a, b), (b, a), (a[::-1], b), (a, b[::-1])):
        assert float(geo.segment_segment_distance(x, y)) <= 1e-12 * length
    lifted = b + np.array([0.0, 0.0, 0.25])  # skew by 0.25 m: distance exactly 0.25
    assert abs(float(geo.segment_segment_distance(a, lifted)) - 0.25) <= 1e-12 * length


@pytest.mark.parametrize("length", [1e-6, 5e-7, 1e-9])
def test_short_segments_are_not_points(length):
    """Regression: segments with squared length <= 1e-12 were treated as their first end."""
    a = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, length]])
    assert float(geo.segment_segment_distance(a, a[::-1])) == 0.0
    assert float(geo.segment_segment_distance(a, a[1:].repeat(2, axis=0))) == 0.0
    assert float(geo.point_segment_distance(a[1], a)) == 0.0
    # Crossing short segments.
    b = np.array([[-length, 0.0, 0.5 * length], [length, 0.0, 0.5 * length]])
    assert float(geo.segment_segment_distance(a, b)) <= 1e-15


# ----------------------------------------------------------------------------------------------
# Point / segment


@MANY
@given(segments(), vec3, st.sampled_from([1.0, 1e-3, 30.0]))
def test_point_segment_distance_vs_brute_force(ends, x, spread):
    x = ends[0] + spread * x
    eps = tol(ends, x)
    d = float(geo.point_segment_distance(x, ends))
    grid, res = grid_point_segment(x, ends)
    assert d >= 0.0
    assert d <= grid + eps
    assert d >= grid - res - eps
    assert abs(d - float(ref_point_segment(x, ends))) <= eps
    assert d <= float(np.linalg.norm(x - ends[0])) + eps
    assert d <= float(np.linalg.norm(x - ends[1])) + eps


@MANY
@given(segments(), vec3, st.sampled_from([1.0, 1e-3, 30.0]))
def test_point_segment_closest_parameter_gives_the_distance(ends, x, spread):
    """The parameter returned is in [0, 1], its point is at the returned distance, and it is
    the segment-segment closest point's parameter for the point taken as a segment."""
    x = ends[0] + spread * x
    eps = tol(ends, x)
    d, s = (float(a) for a in geo.point_segment_closest(x, ends))
    assert 0.0 <= s <= 1.0
    assert abs(float(np.linalg.norm(x - (ends[0] + s * (ends[1] - ends[0])))) - d) <= eps
    d_seg, _, t = geo.segment_segment_closest(np.stack([x, x]), ends)
    assert abs(d - float(d_seg)) <= eps
    if float(np.dot(ends[1] - ends[0], ends[1] - ends[0])) > 0.0:
        assert abs(s - float(t)) * float(np.linalg.norm(ends[1] - ends[0])) <= eps


@MEDIUM
@given(segments(), st.floats(0.0, 1.0))
def test_point_on_segment_has_zero_distance(ends, s):
    x = ends[0] + s * (ends[1] - ends[0])
    assert float(geo.point_segment_distance(x, ends)) <= tol(ends)


# ----------------------------------------------------------------------------------------------
# Capsule sets


@MEDIUM
@given(st.lists(capsules(), min_size=1, max_size=4), st.lists(capsules(), min_size=1, max_size=4))
def test_capsule_distances_matrix_matches_pairwise(caps_a, caps_b):
    ea, ra = stack_capsules(caps_a)
    eb, rb = stack_capsules(caps_b)
    D = geo.capsule_distances(ea, ra, eb, rb)
    inter = geo.capsules_intersect(ea, ra, eb, rb)
    assert D.shape == (len(caps_a), len(caps_b))
    assert inter.shape == D.shape and inter.dtype == bool
    for i in range(len(caps_a)):
        for j in range(len(caps_b)):
            pair = float(geo.segment_segment_distance(ea[i], eb[j])) - ra[i] - rb[j]
            assert abs(D[i, j] - pair) <= 1e-12 * max(1.0, abs(pair))
    np.testing.assert_array_equal(inter, D <= 0.0)


@MEDIUM
@given(
    segment_pairs(),
    radii,
    st.floats(0.0, 0.999),
    st.sampled_from([0.0, 1e-6, 0.1]),
    seeds,
)
def test_capsules_intersect_when_a_point_is_inside_both(pair, ra, depth, extra, seed):
    a, b = pair
    rng = np.random.default_rng(seed)
    eps = tol(a, b)
    # x lies inside capsule a (strictly, by construction) ...
    x = a[0] + rng.random() * (a[1] - a[0]) + depth * ra * random_unit(rng)
    # ... and inside capsule b, whose radius reaches x with a margin.
    rb = float(ref_point_segment(x, b)) + extra + eps
    assert float(geo.point_segment_distance(x, a)) <= ra + eps
    D = geo.capsule_distances(a[None], np.array([ra]), b[None], np.array([rb]))
    inter = geo.capsules_intersect(a[None], np.array([ra]), b[None], np.array([rb]))
    assert D.shape == (1, 1)
    assert bool(inter[0, 0]), (float(D[0, 0]), ra, rb)


@MEDIUM
@given(segment_pairs(), st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_capsules_not_intersecting_when_brute_force_separates(pair, share, frac):
    a, b = pair
    eps = tol(a, b)
    grid, res = grid_segment_segment(a, b)
    gap = grid - res - eps  # a certified lower bound of the axis distance
    assume(gap > 0.0)
    total = frac * gap * (1.0 - 1e-9)  # ra + rb strictly below the certified bound
    ra, rb = share * total, (1.0 - share) * total
    inter = geo.capsules_intersect(a[None], np.array([ra]), b[None], np.array([rb]))
    D = geo.capsule_distances(a[None], np.array([ra]), b[None], np.array([rb]))
    assert not bool(inter[0, 0])
    assert float(D[0, 0]) > 0.0


@MEDIUM
@given(st.lists(capsules(), min_size=1, max_size=3), st.lists(capsules(), min_size=1, max_size=3))
def test_capsules_intersect_against_grid(caps_a, caps_b):
    ea, ra = stack_capsules(caps_a)
    eb, rb = stack_capsules(caps_b)
    inter = geo.capsules_intersect(ea, ra, eb, rb)
    for i in range(len(caps_a)):
        for j in range(len(caps_b)):
            grid, res = grid_segment_segment(ea[i], eb[j])
            eps = tol(ea[i], eb[j])
            if grid <= ra[i] + rb[j] - eps:  # a sampled axis pair is within reach
                assert inter[i, j]
            if grid - res > ra[i] + rb[j] + eps:  # certified separation
                assert not inter[i, j]


# ----------------------------------------------------------------------------------------------
# Points in capsules


@st.composite
def points_near_capsule(draw, ends: np.ndarray, r: float) -> np.ndarray:
    s = draw(st.floats(-0.3, 1.3))
    rng = np.random.default_rng(draw(seeds))
    factor = draw(st.sampled_from([0.0, 0.5, 0.99, 1.01, 1.5, 3.0]))
    return ends[0] + s * (ends[1] - ends[0]) + factor * max(r, 1e-3) * random_unit(rng)


@MANY
@given(st.data(), capsules())
def test_points_in_capsules_vs_brute_force(data, cap):
    ends, r = cap
    x = data.draw(points_near_capsule(ends, r))
    eps = tol(ends, x)
    inside = bool(geo.points_in_capsules(x, ends, np.float64(r)))
    grid, res = grid_point_segment(x, ends)
    if grid <= r - eps:
        assert inside
    if grid - res > r + eps:
        assert not inside
    exact = float(ref_point_segment(x, ends))
    if exact <= r - eps:
        assert inside
    if exact > r + eps:
        assert not inside


@MEDIUM
@given(st.integers(1, 6), st.data(), seeds)
def test_points_in_union_checks_every_capsule(n, data, seed):
    """Capsules far apart; a point inside exactly one of them, in particular the last one."""
    rng = np.random.default_rng(seed)
    centres = np.arange(n)[:, None] * np.array([10.0, 0.0, 0.0]) + rng.uniform(-1, 1, (n, 3))
    half_axis = random_unit(rng, n) * rng.uniform(0.0, 1.5, (n, 1))
    half_axis[rng.random(n) < 0.2] = 0.0  # some balls
    ends = np.stack([centres - half_axis, centres + half_axis], axis=1)
    radius = rng.uniform(0.05, 1.0, n)
    k = data.draw(st.sampled_from([n - 1, int(rng.integers(0, n))]))
    s = rng.random(3)
    inner = ends[k, 0] + s[:, None] * (ends[k, 1] - ends[k, 0])
    inner = inner + 0.9 * radius[k] * rng.random((3, 1)) * random_unit(rng, 3)
    far = np.array([[5.0, 50.0, 0.0], [-20.0, 0.0, 0.0], [10.0 * n + 5.0, 0.0, 0.0]])
    pts = np.concatenate([inner, far])
    got = geo.points_in_union(pts, ends, radius)
    assert got.shape == (len(pts),) and got.dtype == bool
    assert got[:3].all(), f"point inside capsule {k} of {n} not found"
    assert not got[3:].any()
    # Only capsule k contains the inner points, so dropping it must lose them.
    others = np.arange(n) != k
    if others.any():
        assert not geo.points_in_union(inner, ends[others], radius[others]).any()


@MEDIUM
@given(st.lists(capsules(), min_size=1, max_size=5), seeds)
def test_points_in_union_vs_brute_force(caps, seed):
    ends, radius = stack_capsules(caps)
    rng = np.random.default_rng(seed)
    # Points near random capsules, some in, some out.
    idx = rng.integers(0, len(caps), 40)
    s = rng.uniform(-0.2, 1.2, 40)
    base = ends[idx, 0] + s[:, None] * (ends[idx, 1] - ends[idx, 0])
    pts = base + rng.uniform(0.0, 2.0, (40, 1)) * (radius[idx, None] + 1e-3) * random_unit(rng, 40)
    got = geo.points_in_union(pts, ends, radius)
    assert got.shape == (40,)
    eps = tol(ends, pts)
    exact = np.stack([ref_point_segment(pts, e) for e in ends], axis=1)  # (S, N)
    surely_in = (exact <= radius[None, :] - eps).any(axis=1)
    surely_out = (exact > radius[None, :] + eps).all(axis=1)
    assert got[surely_in].all()
    assert not got[surely_out].any()
    # Same as asking each capsule separately.
    per_capsule = np.stack(
        [geo.points_in_capsules(pts, ends[i], radius[i]) for i in range(len(caps))], axis=1
    )
    np.testing.assert_array_equal(got, per_capsule.any(axis=1))


# ----------------------------------------------------------------------------------------------
# Enclosing balls and capsules


@st.composite
def ball_pairs(draw) -> tuple[np.ndarray, float, np.ndarray, float]:
    kind = draw(st.sampled_from(["random", "nested", "nested_rev", "concentric", "touching"]))
    c1, r1 = draw(vec3), draw(radii)
    if kind == "random":
        return c1, r1, draw(vec3), draw(radii)
    if kind == "concentric":
        return c1, r1, c1.copy(), draw(radii)
    if kind == "touching":  # ball 2 internally tangent to ball 1
        r2 = draw(st.floats(0.0, 1.0)) * r1
        return c1, r1, c1 + (r1 - r2) * draw(unit3), r2
    # nested: ball 2 strictly inside ball 1
    r1 = max(r1, 1e-2)
    off = draw(st.floats(0.0, 0.95)) * r1
    r2 = draw(st.floats(0.0, 0.99)) * (r1 - off)
    c2 = c1 + off * draw(unit3)
    if kind == "nested_rev":
        return c2, r2, c1, r1
    return c1, r1, c2, r2


@MANY
@given(ball_pairs(), seeds)
@example(  # centres 3e-161 m apart (subnormal): the test's own direction along them came out
    # 1.0016 long, a point 0.16 % off ball 1's surface, not a miss of the enclosing ball
    balls=(np.zeros(3), 0.01, np.array([0.0, 1.6054590e-161, 2.4081885e-161]), 0.0),
    seed=0,
)
def test_ball_enclosing_balls_contains_and_minimal(balls, seed):
    c1, r1, c2, r2 = balls
    eps = tol(c1, c2)
    centre, radius = geo.ball_enclosing_balls(c1, np.float64(r1), c2, np.float64(r2))
    radius = float(radius)
    rng = np.random.default_rng(seed)
    dirs = random_unit(rng, 300)
    d = float(np.linalg.norm(c2 - c1))
    if d > 0.0:  # the extreme points along the centre line (a unit vector even when the
        u = (c2 - c1) / d  # centres are subnormally close: dividing by d alone is off there)
        u = u / np.linalg.norm(u)
        dirs = np.concatenate([dirs, u[None], -u[None]])
    for c, r in ((c1, r1), (c2, r2)):
        surface = c + r * dirs
        assert np.all(np.linalg.norm(surface - centre, axis=-1) <= radius + eps)
    # Minimal: the formula's radius (no ball containing both can be smaller).
    expected = max(r1, r2, 0.5 * (d + r1 + r2))
    assert abs(radius - expected) <= eps
    # ... and indeed the two far points along the centre line are 2 * expected apart.
    if d > 0.0 and expected == 0.5 * (d + r1 + r2):
        far1, far2 = c1 - r1 * u, c2 + r2 * u
        assert float(np.linalg.norm(far1 - far2)) >= 2.0 * radius - 2.0 * eps


@MEDIUM
@given(segments(), radii, vec3, st.sampled_from([1.0, 0.1, 1e-6, 0.0]), radii, seeds)
def test_capsule_enclosing_capsules_contains_both(a, ra, shift, amount, rb, seed):
    rng = np.random.default_rng(seed)
    # b: the same link displaced (translated plus a random perturbation of each end).
    b = a + amount * shift + amount * rng.normal(size=(2, 3))
    ends, radius = geo.capsule_enclosing_capsules(a, np.float64(ra), b, np.float64(rb))
    assert ends.shape == (2, 3) and np.shape(radius) == ()
    radius = float(radius)
    eps = tol(a, b)
    for seg, r in ((a, ra), (b, rb)):
        n = 500
        s = np.concatenate([rng.random(n), [0.0, 1.0]])
        base = seg[0] + s[:, None] * (seg[1] - seg[0])
        dirs = random_unit(rng, n + 2)
        depth = np.concatenate([rng.random(n // 2) ** (1 / 3), np.ones(n - n // 2 + 2)])
        pts = base + (r * depth)[:, None] * dirs
        assert np.all(ref_point_segment(pts, ends) <= radius + eps)
    if amount == 0.0:
        assert abs(radius - max(ra, rb)) <= eps


# ----------------------------------------------------------------------------------------------
# Volumes


def mc_capsule_volume(ends: np.ndarray, r: float, rng: np.random.Generator, n: int):
    lo = ends.min(axis=0) - r
    hi = ends.max(axis=0) + r
    box = float(np.prod(hi - lo))
    pts = lo + rng.random((n, 3)) * (hi - lo)
    share = float(np.mean(ref_point_segment(pts, ends) <= r))
    return box * share, box * math.sqrt(share * (1.0 - share) / n)


@MC
@given(segments(), st.floats(0.05, 1.5), seeds)
def test_capsule_volume_vs_monte_carlo(ends, r, seed):
    assume(seg_len(ends) < 20.0)  # keep the sampling box from being mostly empty
    vol = float(geo.capsule_volume(ends, np.float64(r)))
    est, se = mc_capsule_volume(ends, r, np.random.default_rng(seed), 40_000)
    assert abs(vol - est) <= 5.0 * se + 1e-12


def test_capsule_volume_known_values():
    ball = np.zeros((2, 3))
    assert abs(float(geo.capsule_volume(ball, np.float64(2.0))) - 32.0 / 3.0 * math.pi) < 1e-12
    stick = np.array([[0.0, 0.0, 0.0], [0.0, 3.0, 4.0]])
    expected = math.pi * 0.25 * 5.0 + 4.0 / 3.0 * math.pi * 0.125
    assert abs(float(geo.capsule_volume(stick, np.float64(0.5))) - expected) < 1e-12
    assert float(geo.capsule_volume(stick, np.float64(0.0))) == 0.0


@MC
@given(st.integers(1, 4), seeds)
def test_union_volume_mc_disjoint_is_sum(n, seed):
    rng = np.random.default_rng(seed)
    centres = np.arange(n)[:, None] * np.array([4.0, 0.0, 0.0]) + rng.uniform(-0.2, 0.2, (n, 3))
    half_axis = random_unit(rng, n) * rng.uniform(0.0, 0.8, (n, 1))
    ends = np.stack([centres - half_axis, centres + half_axis], axis=1)
    radius = rng.uniform(0.2, 1.0, n)  # reach <= 1.8 from the centre: disjoint (spacing 4)
    assert (
        geo.segment_segment_distance(ends[:, None], ends[None, :])[~np.eye(n, dtype=bool)].min(
            initial=np.inf
        )
        > 2.0 * radius.max()
    )
    vol, se = geo.union_volume_mc(ends, radius, 60_000, rng)
    expected = float(np.sum(geo.capsule_volume(ends, radius)))
    assert se > 0.0
    assert abs(vol - expected) <= 5.0 * se, (vol, expected, se)


@MC
@given(segments(), st.floats(0.1, 1.0), st.integers(1, 4), seeds)
def test_union_volume_mc_identical_is_one(ends, r, copies, seed):
    assume(seg_len(ends) < 20.0)
    rng = np.random.default_rng(seed)
    all_ends = np.repeat(ends[None], copies, axis=0)
    if copies > 1:  # identical capsules, possibly with reversed ends
        all_ends[1] = ends[::-1]
    vol, se = geo.union_volume_mc(all_ends, np.full(copies, r), 40_000, rng)
    expected = float(geo.capsule_volume(ends, np.float64(r)))
    assert abs(vol - expected) <= 5.0 * se + 1e-12, (vol, expected, se)


@MC
@given(st.lists(capsules(st.floats(0.05, 1.5)), min_size=2, max_size=4), seeds)
def test_union_volume_mc_bounds(caps, seed):
    ends, radius = stack_capsules(caps)
    assume(all(seg_len(e) < 20.0 for e in ends))
    vol, se = geo.union_volume_mc(ends, radius, 40_000, np.random.default_rng(seed))
    vols = geo.capsule_volume(ends, radius)
    assert vol <= float(vols.sum()) + 5.0 * se
    assert vol >= float(vols.max()) - 5.0 * se


# ----------------------------------------------------------------------------------------------
# Boxes


@MEDIUM
@given(rotations())
def test_rotation_strategy_is_proper(R):
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert abs(np.linalg.det(R) - 1.0) < 1e-12


@MANY
@given(boxes(), vec3, st.sampled_from([0.3, 1.0, 3.0]), seeds)
def test_point_box_distance_vs_brute_force(box, x, spread, seed):
    T, h = box
    x = T[:3, 3] + spread * x
    eps = tol(T, x)
    d = float(geo.point_box_distance(x, T, h))
    assert d >= 0.0
    assert abs(d - float(ref_point_box(x, T, h))) <= eps
    # Never larger than the distance to any sampled point of the solid box.
    samples = box_samples(T, h, np.random.default_rng(seed), 2000)
    assert d <= float(np.min(np.linalg.norm(samples - x, axis=-1))) + eps
    # Zero inside: points of the solid box.
    inside = box_samples(T, h, np.random.default_rng(seed + 1), 50)
    assert np.all(geo.point_box_distance(inside, T, h) <= eps)


@MANY
@given(st.data(), boxes())
def test_segment_box_distance_vs_brute_force(data, box):
    T, h = box
    ends = data.draw(box_segments(T, h))
    eps = tol(T, ends)
    d = float(geo.segment_box_distance(ends, T, h))
    pts = seg_points(ends, GRID_1D)
    sampled = ref_point_box(pts, T, h)
    grid = float(sampled.min())
    res = seg_len(ends) / (2 * (GRID_1D - 1))
    assert d >= 0.0
    assert d <= grid + eps, f"exceeds sampled minimum {grid}"
    assert d >= grid - res - eps, f"below sampled minimum {grid} minus resolution {res}"
    # Sharp reference: the distance to a convex set along a segment is convex.
    p, q = ends
    sharp = ternary_min(lambda s: float(ref_point_box(p + s * (q - p), T, h)))
    assert abs(d - sharp) <= eps, (d, sharp)
    # A degenerate segment is a point.
    if np.array_equal(p, q):
        assert abs(d - float(geo.point_box_distance(p, T, h))) <= eps


def test_segment_box_interior_minimum_of_a_flat_piece():
    """Regression: a piece with curvature qa <= 1e-12 was evaluated at its start only."""
    T, h = np.eye(4), np.ones(3)
    ends = np.array([[1 + 1e-7, 1 + 5e-7, 0.0], [1 + 5e-7, 1 + 1e-7, 0.0]])
    expected = math.hypot(3e-7, 3e-7)  # at s = 0.5; the ends are 5.1e-7 away
    assert abs(float(geo.segment_box_distance(ends, T, h)) - expected) <= 1e-15


@MEDIUM
@given(st.data(), boxes())
def test_segment_through_box_is_zero(data, box):
    T, h = box
    R, p = T[:3, :3], T[:3, 3]
    u = np.array(data.draw(st.tuples(*[st.floats(-1.0, 1.0)] * 3)))
    x = p + R @ (u * h)
    e = data.draw(unit3) * data.draw(st.floats(1e-3, 6.0))
    w = data.draw(st.floats(0.0, 1.0))
    ends = np.stack([x - w * e, x + (1.0 - w) * e])
    assert float(geo.segment_box_distance(ends, T, h)) <= tol(T, ends)


@MEDIUM
@given(st.lists(boxes(), min_size=1, max_size=3), st.lists(capsules(), min_size=1, max_size=3))
def test_capsule_box_distances_matrix(box_list, caps):
    T = np.stack([b[0] for b in box_list])
    h = np.stack([b[1] for b in box_list])
    ends, radius = stack_capsules(caps)
    D = geo.capsule_box_distances(ends, radius, T, h)
    assert D.shape == (len(caps), len(box_list))
    for i in range(len(caps)):
        pts = seg_points(ends[i], GRID_1D)
        res = seg_len(ends[i]) / (2 * (GRID_1D - 1))
        for j in range(len(box_list)):
            pair = float(geo.segment_box_distance(ends[i], T[j], h[j])) - radius[i]
            assert abs(D[i, j] - pair) <= 1e-12 * max(1.0, abs(pair))
            grid = float(ref_point_box(pts, T[j], h[j]).min()) - radius[i]
            eps = tol(T[j], ends[i])
            assert D[i, j] <= grid + eps
            assert D[i, j] >= grid - res - eps


# ----------------------------------------------------------------------------------------------
# Broadcasting: batched calls equal one-by-one calls


def _close(batched, single, where) -> None:
    np.testing.assert_allclose(batched, single, rtol=1e-12, atol=1e-12, err_msg=str(where))


@FAST
@given(
    st.lists(segment_pairs(), min_size=1, max_size=3),
    st.lists(segment_pairs(), min_size=1, max_size=3),
)
def test_broadcast_segment_functions(pairs_a, pairs_b):
    A = np.stack([p[0] for p in pairs_a])  # (I, 2, 3)
    B = np.stack([p[1] for p in pairs_b])  # (J, 2, 3)
    d, s, t = geo.segment_segment_closest(A[:, None], B[None, :])
    dd = geo.segment_segment_distance(A[:, None], B[None, :])
    assert d.shape == s.shape == t.shape == dd.shape == (len(A), len(B))
    pts = A[:, 0, :]  # (I, 3) as points
    pd = geo.point_segment_distance(pts[:, None], B[None, :])
    assert pd.shape == (len(A), len(B))
    radius = np.linspace(0.1, 1.0, len(B))
    inside = geo.points_in_capsules(pts[:, None], B[None, :], radius[None, :])
    assert inside.shape == (len(A), len(B))
    for i in range(len(A)):
        for j in range(len(B)):
            d1, s1, t1 = geo.segment_segment_closest(A[i], B[j])
            _close(d[i, j], d1, (i, j))
            _close(s[i, j], s1, (i, j))
            _close(t[i, j], t1, (i, j))
            _close(dd[i, j], geo.segment_segment_distance(A[i], B[j]), (i, j))
            _close(pd[i, j], geo.point_segment_distance(pts[i], B[j]), (i, j))
            assert inside[i, j] == geo.points_in_capsules(pts[i], B[j], radius[j])


@FAST
@given(st.lists(ball_pairs(), min_size=1, max_size=4), st.lists(capsules(), min_size=2, max_size=4))
def test_broadcast_enclosing_and_volume(balls, caps):
    c1 = np.stack([b[0] for b in balls])
    r1 = np.array([b[1] for b in balls])
    c2 = np.stack([b[2] for b in balls])
    r2 = np.array([b[3] for b in balls])
    # (I, 1) against (1, I): all combinations.
    centre, radius = geo.ball_enclosing_balls(c1[:, None], r1[:, None], c2[None], r2[None])
    assert centre.shape == (len(balls), len(balls), 3) and radius.shape == centre.shape[:2]
    for i in range(len(balls)):
        for j in range(len(balls)):
            ci, ri = geo.ball_enclosing_balls(c1[i], r1[i], c2[j], r2[j])
            _close(centre[i, j], ci, (i, j))
            _close(radius[i, j], ri, (i, j))
    ends, rad = stack_capsules(caps)
    ends_b, rad_b = ends[::-1] + 0.1, rad[::-1]
    e2, r2c = geo.capsule_enclosing_capsules(ends[:, None], rad[:, None], ends_b[None], rad_b[None])
    assert e2.shape == (len(caps), len(caps), 2, 3) and r2c.shape == (len(caps), len(caps))
    vols = geo.capsule_volume(ends[:, None].repeat(2, axis=1), np.stack([rad, rad], axis=1))
    assert vols.shape == (len(caps), 2)
    for i in range(len(caps)):
        _close(vols[i, 1], geo.capsule_volume(ends[i], rad[i]), i)
        for j in range(len(caps)):
            ej, rj = geo.capsule_enclosing_capsules(ends[i], rad[i], ends_b[j], rad_b[j])
            _close(e2[i, j], ej, (i, j))
            _close(r2c[i, j], rj, (i, j))


@FAST
@given(st.lists(boxes(), min_size=1, max_size=3), st.lists(segments(), min_size=1, max_size=3))
def test_broadcast_box_functions(box_list, segs):
    T = np.stack([b[0] for b in box_list])  # (J, 4, 4)
    h = np.stack([b[1] for b in box_list])  # (J, 3)
    E = np.stack(segs)  # (I, 2, 3)
    pts = E[:, 1, :]
    pd = geo.point_box_distance(pts[:, None], T[None], h[None])
    sd = geo.segment_box_distance(E[:, None], T[None], h[None])
    tp = geo.transform_points(T[None], pts[:, None])
    assert pd.shape == sd.shape == (len(E), len(T)) and tp.shape == (len(E), len(T), 3)
    for i in range(len(E)):
        for j in range(len(T)):
            _close(pd[i, j], geo.point_box_distance(pts[i], T[j], h[j]), (i, j))
            _close(sd[i, j], geo.segment_box_distance(E[i], T[j], h[j]), (i, j))
            _close(tp[i, j], (T[j] @ np.append(pts[i], 1.0))[:3], (i, j))
            _close(geo.transform_points(T[j], pts[i]), T[j, :3, :3] @ pts[i] + T[j, :3, 3], 0)
    # One box pose, several sizes (only the half extents carry the batch axis).
    sizes = np.stack([b[1] for b in box_list])
    pd1 = geo.point_box_distance(pts[0], T[0], sizes)
    sd1 = geo.segment_box_distance(E[0], T[0], sizes)
    assert pd1.shape == sd1.shape == (len(sizes),)
    for j in range(len(sizes)):
        _close(pd1[j], geo.point_box_distance(pts[0], T[0], sizes[j]), j)
        _close(sd1[j], geo.segment_box_distance(E[0], T[0], sizes[j]), j)


def test_effective_volume_is_the_per_part_intersection() -> None:
    """``effective_volume_mc``: one model alone gives its union's volume; the same model twice
    too; two models whose capsules for the parts are disjoint give 0; a model nested in another
    gives the inner one's volume (within 4 Monte-Carlo standard errors)."""
    from sara_app.geometry.shapes import capsule_volume, effective_volume_mc

    rng = np.random.default_rng(3)
    ends = np.array([[[0.0, 0, 0], [0.3, 0, 0]], [[0.0, 0.5, 0], [0.0, 0.5, 0.2]]])
    radius = np.array([0.1, 0.15])
    maps = [np.array([0, 1])]
    exact = float(capsule_volume(ends[0], radius[0]) + capsule_volume(ends[1], radius[1]))
    v, err = effective_volume_mc([(ends, radius)], maps, 200_000, rng)
    assert abs(v - exact) <= 4 * err + 1e-12
    v, err = effective_volume_mc([(ends, radius), (ends, radius)], maps * 2, 200_000, rng)
    assert abs(v - exact) <= 4 * err + 1e-12
    far = (ends + 5.0, radius)
    assert effective_volume_mc([(ends, radius), far], maps * 2, 50_000, rng)[0] == 0.0
    big = (ends, radius + 0.2)  # contains the first model's capsules
    v, err = effective_volume_mc([(ends, radius), big], maps * 2, 200_000, rng)
    assert abs(v - exact) <= 4 * err + 1e-12
    # a part held by another model's single ball: the intersection with that ball
    ball = (np.array([[[0.15, 0.0, 0.0], [0.15, 0.0, 0.0]]]), np.array([0.05]))
    v, err = effective_volume_mc([(ends[:1], radius[:1]), ball], [np.array([0]), np.array([0])],
                                 200_000, rng)  # fmt: skip
    assert abs(v - 4.0 / 3.0 * np.pi * 0.05**3) <= 4 * err + 1e-12
