"""The compiled capsule kernels (``sara_app.geometry.shape_kernels``) against the numpy references.

* ``segment_closest`` gives the distance of ``geometry.segment_segment_closest`` (points,
  parallel, anti-parallel, collinear, nearly parallel pairs), and its parameters lie in [0, 1]
  and realise that distance.
* ``point_segment_gap`` gives the distance of ``geometry.point_segment_distance`` (point
  segments, points beyond either end, NaN coordinates).
* ``pair_distances`` / ``set_pair_distances`` against ``capsule_distances`` and the numpy
  ``all_pairs``, ``box_distances`` against the reference's ``segment_box_closest``; ``pair_gaps``
  equals ``pair_distances`` wherever a pair may touch and is a positive lower bound elsewhere;
  so does ``box_axis_gaps`` (against ``box_distances``, for every radius of the capsule).
* ``set_neighbours`` (a breadth-first search's step over one capsule set) finds exactly the
  unlabelled, paired capsules whose ``set_pair_distances`` distance is <= 0 or NaN.
* ``capsule_sets_check`` against all pairs from ``geometry.capsule_distances``: ``hit`` exactly
  where an interval's smallest distance is <= 0 (round-off ties aside), nothing outside
  ``todo``, the returned distance is the exact smallest one over the checked intervals, and a
  NaN capsule always counts as a hit.
"""

from __future__ import annotations

import numpy as np
from contact_reference import segment_box_closest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from soa_reference import all_pairs

from sara_app.geometry import shapes as geo
from sara_app.geometry.shape_kernels import (
    box_axis_gaps,
    box_distances,
    capsule_sets_check,
    gap_block,
    pair_distances,
    pair_gaps,
    point_segment_gap,
    segment_closest,
    set_gap_interval,
    set_gap_scratch,
    set_neighbours,
    set_pair_distances,
)

SETTINGS = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
BAND_M = 1e-9  # round-off ties are not compared

coord = st.floats(-3.0, 3.0, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(coord, coord, coord).map(np.array)
scale = st.floats(-2.0, 2.0, allow_nan=False).filter(lambda x: abs(x) > 1e-6 or x == 0.0)


@st.composite
def segment_pair(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    kind = draw(
        st.sampled_from(
            ["general", "point_a", "point_b", "points", "parallel", "collinear", "near_parallel"]
        )
    )
    p, d, q, e = draw(vec3), draw(vec3), draw(vec3), draw(vec3)
    a, b = np.stack([p, p + d]), np.stack([q, q + e])
    if kind == "point_a":
        a = np.stack([p, p])
    elif kind == "point_b":
        b = np.stack([q, q])
    elif kind == "points":
        a, b = np.stack([p, p]), np.stack([q, q])
    elif kind == "parallel":
        b = np.stack([q, q + draw(scale) * d])
    elif kind == "collinear":
        b = np.stack([p + draw(scale) * d, p + draw(scale) * d])
    elif kind == "near_parallel":
        b = np.stack([q, q + draw(scale) * d + draw(st.floats(1e-12, 1e-4)) * e])
    return a, b


@SETTINGS
@given(st.lists(segment_pair(), min_size=1, max_size=16))
def test_segment_closest_equals_numpy(pairs: list) -> None:
    for a, b in pairs:
        tol = 1e-9 * max(1.0, float(np.abs(a).max()), float(np.abs(b).max()))
        d, s, t = segment_closest(*a.ravel(), *b.ravel())
        d_ref = float(geo.segment_segment_closest(a, b)[0])
        assert abs(d - d_ref) <= tol
        assert 0.0 <= s <= 1.0 and 0.0 <= t <= 1.0
        pa, pb = a[0] + s * (a[1] - a[0]), b[0] + t * (b[1] - b[0])
        assert abs(float(np.linalg.norm(pa - pb)) - d) <= tol


@st.composite
def capsule_sets(draw: st.DrawFn) -> dict:
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    K, C, L = draw(st.integers(1, 6)), draw(st.integers(1, 14)), draw(st.integers(1, 9))
    Ka, Kr = draw(st.sampled_from([1, K])), draw(st.sampled_from([1, K]))
    spread = draw(st.sampled_from([0.2, 0.6, 1.5]))
    a0 = rng.normal(scale=spread, size=(Ka, C, 3))
    a1 = a0 + rng.normal(scale=0.3, size=(Ka, C, 3)) * (rng.random((Ka, C, 1)) < 0.8)
    b0 = rng.normal(scale=spread, size=(K, L, 3))
    b1 = b0 + rng.normal(scale=0.3, size=(K, L, 3)) * (rng.random((K, L, 1)) < 0.8)
    a_ends = np.stack([a0, a1], axis=2)
    if Ka == K and draw(st.booleans()):  # the same axes on every interval, radii differ
        a_ends = np.repeat(a_ends[:1], K, axis=0)
    return dict(
        a_ends=a_ends,
        a_rad=rng.uniform(0.01, 0.3, size=(Kr, C)),
        b_ends=np.stack([b0, b1], axis=2),
        b_rad=rng.uniform(0.01, 0.2, size=(K, L)),
        todo=rng.random(K) < 0.8,
    )


def _brute(c: dict) -> np.ndarray:
    K, C = c["b_ends"].shape[0], c["a_ends"].shape[1]
    a_ends = np.broadcast_to(c["a_ends"], (K, C, 2, 3))
    a_rad = np.broadcast_to(c["a_rad"], (K, C))
    return np.array(
        [
            geo.capsule_distances(a_ends[k], a_rad[k], c["b_ends"][k], c["b_rad"][k]).min()
            for k in range(K)
        ]
    )


@SETTINGS
@given(capsule_sets())
def test_capsule_sets_check_matches_brute_force(c: dict) -> None:
    K = c["b_ends"].shape[0]
    hit = np.ones(K, dtype=bool)
    best = capsule_sets_check(c["a_ends"], c["a_rad"], c["b_ends"], c["b_rad"], c["todo"], hit)
    dmin = _brute(c)
    todo = c["todo"]
    assert not hit[~todo].any()
    assert np.all(hit[todo & (dmin <= -BAND_M)])  # sound: every overlap is a hit
    assert not hit[todo & (dmin > BAND_M)].any()  # and exact
    expected = dmin[todo].min() if todo.any() else np.inf
    assert best == expected or abs(best - expected) <= 1e-12


@SETTINGS
@given(capsule_sets(), st.integers(0, 3))
def test_nan_capsule_is_a_hit(c: dict, which: int) -> None:
    K = c["b_ends"].shape[0]
    k = K - 1
    c["todo"][k] = True
    if which == 0:
        c["b_ends"][k, 0, 1, 2] = np.nan
    elif which == 1:
        c["b_rad"][k, -1] = np.nan
    elif which == 2:
        c["a_ends"][-1, 0, 0, 0] = np.nan
    else:
        c["a_rad"][-1, -1] = np.nan
    c["b_ends"][k] += 100.0  # far apart: only the NaN can make a hit
    hit = np.zeros(K, dtype=bool)
    capsule_sets_check(c["a_ends"], c["a_rad"], c["b_ends"], c["b_rad"], c["todo"], hit)
    assert hit[k]


def test_accepts_views_and_read_only_arrays() -> None:
    """Broadcast (read-only, zero-stride) and transposed inputs need no new compilation."""
    a = np.broadcast_to(np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]]), (3, 4, 2, 3))
    r = np.broadcast_to(np.full(4, 0.1), (3, 4))
    b = np.asfortranarray(np.array([[[[0.5, 0.5, 0.0], [0.5, 1.0, 0.0]]]] * 3))
    rb = np.full((3, 1), 0.2)
    hit = np.zeros(3, dtype=bool)
    best = capsule_sets_check(a, r, b, rb, np.ones(3, dtype=bool), hit)
    assert not hit.any() and abs(best - 0.2) < 1e-15
    assert len(capsule_sets_check.signatures) == 1


@SETTINGS
@given(capsule_sets())
def test_pair_distances_equal_capsule_distances(c: dict) -> None:
    K, C = c["b_ends"].shape[0], c["a_ends"].shape[1]
    L = c["b_ends"].shape[1]
    out = np.empty((K, C, L))
    touch = pair_distances(c["a_ends"], c["a_rad"], c["b_ends"], c["b_rad"], out)
    assert touch == bool((out <= 0.0).any())
    a_ends = np.broadcast_to(c["a_ends"], (K, C, 2, 3))
    a_rad = np.broadcast_to(c["a_rad"], (K, C))
    for k in range(K):
        ref = geo.capsule_distances(a_ends[k], a_rad[k], c["b_ends"][k], c["b_rad"][k])
        np.testing.assert_allclose(out[k], ref, rtol=0, atol=1e-12)


@SETTINGS
@given(capsule_sets(), st.booleans())
def test_pair_gaps_are_exact_where_pairs_may_touch(c: dict, nan: bool) -> None:
    """Exact distance wherever it is at most the sphere slack (so the same contact pairs),
    a lower bound above the slack elsewhere; NaN input stays NaN (a contact)."""
    if nan:
        c["b_ends"][-1, 0, 1, 2] = np.nan
    K, C, L = c["b_ends"].shape[0], c["a_ends"].shape[1], c["b_ends"].shape[1]
    exact, gaps = np.empty((2, K, C, L))
    touch = pair_distances(c["a_ends"], c["a_rad"], c["b_ends"], c["b_rad"], exact)
    assert pair_gaps(c["a_ends"], c["a_rad"], c["b_ends"], c["b_rad"], gaps) == touch
    np.testing.assert_array_equal(np.isnan(gaps), np.isnan(exact))
    may_touch = ~(exact > 1e-9)
    np.testing.assert_array_equal(gaps[may_touch], exact[may_touch])
    bound = ~np.isnan(exact) & (gaps != exact)
    assert np.all(gaps[bound] > 1e-9) and np.all(gaps[bound] <= exact[bound] + 1e-12)


@SETTINGS
@given(capsule_sets())
def test_set_pair_distances_equal_all_pairs(c: dict) -> None:
    ends, rad = c["a_ends"], c["a_rad"]
    K, N = max(ends.shape[0], rad.shape[0]), ends.shape[1]
    d, s = np.empty((2, K, N, N))
    set_pair_distances(ends, rad, d, s)
    e = np.broadcast_to(ends, (K, N, 2, 3))
    r = np.broadcast_to(rad, (K, N))
    d_ax, s_ref, _ = all_pairs(np.ascontiguousarray(e))
    np.testing.assert_allclose(d, d_ax - r[:, :, None] - r[:, None, :], rtol=0, atol=1e-12)
    off = ~np.eye(N, dtype=bool)
    pa = e[:, :, None, 0] + s[..., None] * (e[:, :, None, 1] - e[:, :, None, 0])
    pb = e[:, None, :, 0] + s.transpose(0, 2, 1)[..., None] * (e[:, None, :, 1] - e[:, None, :, 0])
    ax = np.linalg.norm(pa - pb, axis=-1)  # the parameters realise the distance
    np.testing.assert_allclose(ax[:, off], d_ax[:, off], rtol=0, atol=1e-12)
    assert np.array_equal(s[:, ~off], np.zeros((K, N)))
    np.testing.assert_allclose(s[:, off], s_ref[:, off], rtol=0, atol=1e-9)


@SETTINGS
@given(capsule_sets(), st.integers(0, 2**32 - 1), st.sampled_from(["", "ends", "radius"]))
def test_set_neighbours_are_the_unlabelled_masked_capsules_that_may_touch(
    c: dict, seed: int, nan: str
) -> None:
    """Each interval in order, each capsule ``a`` and a random labelling: ``set_neighbours``
    labels and lists exactly the unlabelled capsules paired with ``a`` whose exact distance
    (``set_pair_distances``) is <= 0 or NaN, and touches no other label; its broad phases
    (blocks of ``gap_block``, then each capsule's sphere) never skip such a pair, a NaN end
    or radius (a NaN distance) included."""
    ends, rad = c["a_ends"].copy(), c["a_rad"].copy()
    K, N = max(ends.shape[0], rad.shape[0]), ends.shape[1]
    rng = np.random.default_rng(seed)
    if nan == "ends":
        ends[-1, rng.integers(N), 0, 0] = np.nan
    elif nan == "radius":
        rad[-1, rng.integers(N)] = np.nan
    mask = rng.random((N, N)) < 0.7
    mask = (mask | mask.T) & ~np.eye(N, dtype=bool)
    exact, s = np.empty((2, K, N, N))
    set_pair_distances(ends, rad, exact, s)
    sph, axis = set_gap_scratch(N)
    assert sph.shape[0] == N + -(-N // gap_block)
    ke, kr = -1, -1
    for k in range(K):
        ke, kr = set_gap_interval(ends, rad, k, K, (ke, kr), sph, axis)
        for a in range(N):
            label = np.where(rng.random(N) < 0.3, 7, -1).astype(np.int64)
            before = label.copy()
            found = np.full(N, -5, dtype=np.int64)
            tail = set_neighbours(ends, rad, ke, kr, a, mask, sph, axis, label, 3, found, 1)
            expect = np.flatnonzero((before < 0) & mask[a] & ~(exact[k, a] > 0.0))
            np.testing.assert_array_equal(found[1:tail], expect)
            assert found[0] == -5 and np.all(found[tail:] == -5)
            np.testing.assert_array_equal(label[expect], 3)
            others = np.ones(N, dtype=bool)
            others[expect] = False
            np.testing.assert_array_equal(label[others], before[others])


def test_set_neighbours_find_a_capsule_that_just_touches_across_a_block() -> None:
    """Balls in a row overlapping by 1 mm: the block beyond capsule ``a``'s own reaches it by
    1 mm only (its bound is -1 mm), and its neighbour there is found (a broad phase that
    skipped where its bound is above -1.1 mm would miss it); the next one, 0.2 m further, is
    not."""
    N, r = 12, 0.1005
    x = 0.2 * np.arange(N)
    ends = np.zeros((1, N, 2, 3))
    ends[0, :, :, 0] = x[:, None]
    rad = np.full((1, N), r)
    sph, axis = set_gap_scratch(N)
    set_gap_interval(ends, rad, 0, 1, (-1, -1), sph, axis)
    a = gap_block - 1  # the last of the first block
    label = np.full(N, -1, dtype=np.int64)
    label[a] = 0
    found = np.empty(N, dtype=np.int64)
    mask = ~np.eye(N, dtype=bool)
    tail = set_neighbours(ends, rad, 0, 0, a, mask, sph, axis, label, 0, found, 0)
    assert sorted(found[:tail]) == [a - 1, a + 1]


def _pose(rng: np.random.Generator) -> np.ndarray:
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    T = np.eye(4)
    T[:3, :3] = Q * np.sign(np.linalg.det(Q))
    T[:3, 3] = rng.normal(scale=0.3, size=3)
    return T


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(0, 3))
def test_box_distances_equal_segment_box_closest(seed: int, B: int) -> None:
    rng = np.random.default_rng(seed)
    K, N = int(rng.integers(1, 4)), int(rng.integers(1, 8))
    ends = rng.normal(scale=0.6, size=(K, N, 2, 3))
    ends[:, 0, 1] = ends[:, 0, 0]  # a ball
    if rng.random() < 0.5:
        ends[1:] = ends[0]  # the same axes on every interval (computed once, radii differ)
    rad = rng.uniform(0.0, 0.2, (K, N))
    T = np.array([_pose(rng) for _ in range(B)]).reshape(B, 4, 4)
    h = rng.uniform(0.0, 0.4, (B, 3))
    dist, normal = np.empty((K, N, B)), np.empty((K, N, B, 3))
    box_distances(ends, rad, T, h, dist, normal)
    d_ref, p_seg, p_box = segment_box_closest(ends.reshape(-1, 2, 3), T, h)
    np.testing.assert_allclose(dist, d_ref.reshape(K, N, B) - rad[:, :, None], atol=1e-12)
    ref_n = (p_seg - p_box).transpose(1, 2, 0).reshape(K, N, B, 3)
    np.testing.assert_allclose(normal, ref_n, atol=1e-12)
    if B:
        ends[0, 0, 0, 1] = np.nan
        box_distances(ends, rad, T, h, dist, np.empty((0, 0, 0, 3)))
        assert np.isnan(dist[0, 0]).all()


@SETTINGS
@given(st.integers(0, 2**32 - 1), st.integers(0, 3), st.booleans())
def test_box_axis_gaps_give_the_exact_touch_test(seed: int, B: int, nan: bool) -> None:
    """Axis-to-box distance exact wherever the capsule may touch the box for one of its radii,
    else a lower bound above every radius by the slack; a NaN capsule gives NaN."""
    rng = np.random.default_rng(seed)
    Ke, Kr, N = int(rng.integers(1, 4)), int(rng.integers(1, 4)), int(rng.integers(1, 8))
    ends = rng.normal(scale=0.8, size=(Ke, N, 2, 3))
    ends[:, 0, 1] = ends[:, 0, 0]  # a ball
    if nan:
        ends[-1, -1, 1, 2] = np.nan
    rad = rng.uniform(0.0, 0.3, (Kr, N))
    T = np.array([_pose(rng) for _ in range(B)]).reshape(B, 4, 4)
    h = rng.uniform(0.0, 0.4, (B, 3))
    exact, gaps = np.empty((2, Ke, N, B))
    box_distances(ends, np.zeros((1, N)), T, h, exact, np.empty((0, 0, 0, 3)))
    box_axis_gaps(ends, rad, T, h, gaps)
    np.testing.assert_array_equal(np.isnan(gaps), np.isnan(exact))
    r_max = rad.max(axis=0)[None, :, None]
    may_touch = ~(exact - r_max > 1e-9)
    np.testing.assert_array_equal(gaps[may_touch], exact[may_touch])
    bound = ~np.isnan(exact) & ~may_touch
    assert np.all(gaps[bound] - np.broadcast_to(r_max, gaps.shape)[bound] > 1e-9)
    assert np.all(gaps[bound] <= exact[bound] + 1e-12)


def test_below_gaps_drops_exactly_the_pairs_above_a_bound() -> None:
    """A pair's gap becomes inf exactly when every sampled point of the ``a`` capsule lies
    above ``b``'s bound (brute force over its surface's lowest points); the others keep their
    gap; a NaN end or radius never drops a pair; the result says whether any pair may touch."""
    from sara_app.geometry.shape_kernels import below_gaps

    rng = np.random.default_rng(5)
    K, A, B = 3, 6, 4
    ends = rng.uniform(0.0, 2.0, (K, A, 2, 3))
    radius = rng.uniform(0.02, 0.2, (K, A))
    ends[1, 2, 0, 2] = np.nan
    radius[2, 3] = np.nan
    cap_z = rng.uniform(0.0, 2.0, (K, B))
    cap_z[0, 1] = np.inf
    gaps = rng.uniform(-0.1, 0.1, (K, A, B))
    out = gaps.copy()
    touch = below_gaps(ends, radius, cap_z, out)
    s = np.linspace(0.0, 1.0, 201)
    for k in range(K):
        for i in range(A):
            axis_z = ends[k, i, 0, 2] + s * (ends[k, i, 1, 2] - ends[k, i, 0, 2])
            lowest = (axis_z - radius[k, i]).min()  # the sphere sweep's lowest point
            for j in range(B):
                above = bool(lowest > cap_z[k, j])  # NaN: not above
                assert (out[k, i, j] == np.inf) == above, (k, i, j)
                if not above:
                    assert out[k, i, j] == gaps[k, i, j]
    assert touch == bool((~(out > 0.0)).any())


def test_point_segment_gap_is_the_numpy_distance() -> None:
    """Random points against random segments, a tenth of them point segments, some points far
    beyond either end; NaN in any coordinate gives NaN, as numpy does."""
    rng = np.random.default_rng(7)
    n = 4000
    ends = rng.normal(size=(n, 2, 3))
    ends[::10, 1] = ends[::10, 0]  # point segments
    pts = rng.normal(size=(n, 3)) * 3.0
    want = geo.point_segment_distance(pts, ends)
    got = np.array([point_segment_gap(*pts[i], *ends[i, 0], *ends[i, 1]) for i in range(n)])
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    for k in range(9):  # NaN in each coordinate in turn
        args = [*pts[0], *ends[0, 0], *ends[0, 1]]
        args[k] = np.nan
        assert np.isnan(point_segment_gap(*args)), k
