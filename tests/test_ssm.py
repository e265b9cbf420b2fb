"""Property tests of the SSM verifier (``sara_app.safety.ssm``) and of the paired segment
distance it uses, against brute force.

* ``segment_pair_distances`` equals ``segment_segment_distance`` on generated pairs, including
  points, parallel, anti-parallel, collinear and nearly parallel segments.
* ``SsmVerifier.verify`` against all (human capsule, robot capsule) pairs from
  ``capsule_distances``: a model reported free on an interval has no overlapping pair there; an
  interval where every model overlaps is not cleared; ``safe`` is "every interval of every human
  cleared by at least one model"; each model is evaluated exactly on the intervals that no
  earlier model cleared.
"""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from ssm_reference import model_sets

from sara_app.geometry import shapes as geo
from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import MODELS, HumanReach, part_capsules
from sara_app.human.scripted import aim_arm, joints, standing
from sara_app.safety.ssm import SsmVerifier, body_distance, boxes_of

SETTINGS = settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
PARAMS = to_reach_params(load_param_set("schepp2022_table1"), "full")
REACH = HumanReach(PARAMS)
BAND_M = 1e-9  # pairs this close to touching are round-off ties: skipped in exact comparisons

# ----------------------------------------------------------------------------------------------
# segment_pair_distances

coord = st.floats(-3.0, 3.0, allow_nan=False, allow_infinity=False)
vec3 = st.tuples(coord, coord, coord).map(np.array)
scale = st.floats(-2.0, 2.0, allow_nan=False).filter(lambda x: abs(x) > 1e-6 or x == 0.0)


@st.composite
def segment_pair(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """One pair of segments ``(2, 3)``, ``(2, 3)`` of a drawn kind."""
    kind = draw(
        st.sampled_from(
            ["general", "point_a", "point_b", "points", "parallel", "collinear", "near_parallel"]
        )
    )
    p, d, q, e = draw(vec3), draw(vec3), draw(vec3), draw(vec3)
    a = np.stack([p, p + d])
    b = np.stack([q, q + e])
    if kind == "point_a":
        a = np.stack([p, p])
    elif kind == "point_b":
        b = np.stack([q, q])
    elif kind == "points":
        a, b = np.stack([p, p]), np.stack([q, q])
    elif kind == "parallel":
        b = np.stack([q, q + draw(scale) * d])  # also anti-parallel and zero length
    elif kind == "collinear":
        s0, s1 = draw(scale), draw(scale)
        b = np.stack([p + s0 * d, p + s1 * d])
    elif kind == "near_parallel":
        eps = draw(st.floats(1e-12, 1e-4))
        b = np.stack([q, q + draw(scale) * d + eps * e])
    return a, b


@SETTINGS
@given(st.lists(segment_pair(), min_size=1, max_size=24))
def test_segment_pair_distances_equal_general_function(pairs: list) -> None:
    a = np.stack([p[0] for p in pairs])
    b = np.stack([p[1] for p in pairs])
    fast = geo.segment_pair_distances(a, b)
    ref = geo.segment_segment_distance(a, b)
    scale_m = max(1.0, float(np.abs(a).max()), float(np.abs(b).max()))
    assert fast.shape == (len(pairs),)
    assert np.all(np.isfinite(fast))
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-9 * scale_m)
    # and against the definition: never above the distance of the end points to each other
    ends = np.linalg.norm(a[:, :, None] - b[:, None, :], axis=-1).reshape(len(pairs), 4).min(1)
    assert np.all(fast <= ends + 1e-9 * scale_m)


# ----------------------------------------------------------------------------------------------
# SsmVerifier against brute force


def _human(rng: np.random.Generator) -> np.ndarray:
    """A plausible full skeleton ``(15, 3)`` near the origin, arms aimed at random points."""
    xy = tuple(rng.uniform(-0.8, 0.8, 2))
    pose = standing((float(xy[0]), float(xy[1])), float(rng.uniform(-np.pi, np.pi)))
    for side in ("l", "r"):
        if rng.random() < 0.7:
            pose = aim_arm(pose, side, pose.pelvis + rng.normal(scale=0.5, size=3))
    return joints(pose)


@st.composite
def cell(draw: st.DrawFn) -> dict:
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    H = draw(st.integers(1, 3))
    K = draw(st.integers(1, 6))
    L = draw(st.integers(1, 8))
    order = draw(st.permutations(MODELS))
    models = tuple(order[: draw(st.integers(1, len(MODELS)))])
    spread = draw(st.sampled_from([0.3, 0.8, 1.5, 3.0]))
    y = np.stack([_human(rng) for _ in range(H)])
    v = rng.normal(scale=0.6, size=y.shape)
    dv = rng.uniform(0.0, 0.5, size=(H, 15))
    if rng.random() < 0.2:
        dv[0, rng.integers(15)] = np.inf  # no velocity estimate yet for one joint
    age = rng.uniform(0.0, 0.1, H)
    times = np.concatenate([[0.0], np.cumsum(rng.uniform(0.001, 0.05, K))])
    # robot capsules around random joints of the humans
    anchor = y.reshape(-1, 3)[rng.integers(H * 15, size=(K, L))]
    p0 = anchor + rng.normal(scale=spread, size=(K, L, 3))
    p1 = p0 + rng.normal(scale=0.2, size=(K, L, 3)) * (rng.random((K, L, 1)) < 0.8)
    ends = np.stack([p0, p1], axis=2)
    radius = rng.uniform(0.02, 0.15, size=(K, L))
    return dict(models=models, y=y, v=v, dv=dv, age=age, times=times, ends=ends, radius=radius)


def _brute_min_distance(vf: SsmVerifier, c: dict, h: int, name: str) -> np.ndarray:
    """Smallest (human capsule, robot capsule) surface distance per interval ``(K,)``."""
    times, age = c["times"], c["age"][h]
    occ = model_sets(
        vf.reach,
        name,
        c["y"][h : h + 1],
        c["v"][h : h + 1],
        c["dv"][h : h + 1],
        times[:-1] + age,
        times[1:] + age,
    )
    K = c["ends"].shape[0]
    C = occ.ends.shape[2]
    h_ends = np.broadcast_to(occ.ends[0], (K, C, 2, 3))
    h_rad = np.broadcast_to(occ.radius[0], (K, C))
    out = np.empty(K)
    for k in range(K):
        d = geo.capsule_distances(h_ends[k], h_rad[k], c["ends"][k], c["radius"][k])
        out[k] = d.min()
    return out


@SETTINGS
@given(cell())
def test_verifier_matches_brute_force(c: dict) -> None:
    vf = SsmVerifier(REACH, c["models"])
    res = vf.verify(c["y"], c["v"], c["dv"], c["age"], c["times"], c["ends"], c["radius"])
    H, M, K = len(c["y"]), len(c["models"]), c["ends"].shape[0]
    assert res.free.shape == res.evaluated.shape == (H, M, K)
    dist = np.stack(
        [np.stack([_brute_min_distance(vf, c, h, m) for m in c["models"]]) for h in range(H)]
    )  # (H, M, K)
    # sound: a model reported free has no overlapping pair on that interval
    assert np.all(dist[res.free] > -BAND_M), dist[res.free].min()
    # and exact: an evaluated model with a clear gap is reported free, one with overlap is not
    clear_gap = dist > BAND_M
    overlap = dist <= -BAND_M
    assert np.all(res.free[res.evaluated & clear_gap])
    assert not np.any(res.free[overlap])
    # per body part: a part is cleared only where some evaluated model's capsule for it is
    # free of every robot capsule (brute force), and a model free there clears every part
    cleared = res.parts_clear.all(axis=2)  # (H, K)
    assert np.all(cleared[res.free.any(axis=1)])
    sound = np.zeros_like(res.parts_clear)
    for h in range(H):
        for m, name in enumerate(c["models"]):
            caps = _brute_capsule_distances(vf, c, h, name)
            sound[h] |= res.evaluated[h, m][:, None] & (
                caps[:, part_capsules(REACH, name)] > -BAND_M
            )
    assert not np.any(res.parts_clear & ~sound)
    brute_cleared = clear_gap.any(axis=1)
    decided = (clear_gap | overlap).all(axis=1)  # no round-off tie for any model
    assert np.all(cleared[decided & brute_cleared])
    assert res.safe == bool(cleared.all())
    # models in order: the first on every interval, each later one on a subset of the earlier
    # one's intervals, and an interval left out is cleared
    assert res.evaluated[:, 0].all()
    assert not np.any(res.evaluated[:, 1:] & ~res.evaluated[:, :-1])
    assert np.all(cleared[~res.evaluated[:, -1]])


def _brute_capsule_distances(vf: SsmVerifier, c: dict, h: int, name: str) -> np.ndarray:
    """Smallest surface distance of each of the model's capsules to the robot, per interval
    ``(K, C)``."""
    times, age = c["times"], c["age"][h]
    occ = model_sets(vf.reach, name, c["y"][h : h + 1], c["v"][h : h + 1], c["dv"][h : h + 1],
                       times[:-1] + age, times[1:] + age)  # fmt: skip
    K, C = c["ends"].shape[0], occ.ends.shape[2]
    h_ends = np.broadcast_to(occ.ends[0], (K, C, 2, 3))
    h_rad = np.broadcast_to(occ.radius[0], (K, C))
    return np.stack(
        [geo.capsule_distances(h_ends[k], h_rad[k], c["ends"][k], c["radius"][k]).min(axis=1)
         for k in range(K)]
    )  # fmt: skip


@SETTINGS
@given(cell())
def test_verifier_overlap_everywhere_is_unsafe(c: dict) -> None:
    """Robot capsules placed on the humans' joints overlap every model's set: never safe, no
    interval cleared for the human they touch."""
    y = c["y"]
    K, L = c["ends"].shape[:2]
    pts = np.broadcast_to(y[0, 2], (K, L, 3))  # the first human's pelvis, every interval
    ends = np.stack([pts, pts], axis=2)
    vf = SsmVerifier(REACH, c["models"])
    res = vf.verify(y, c["v"], c["dv"], c["age"], c["times"], ends, c["radius"])
    assert not res.safe
    assert not res.free[0].any()
    assert np.all(res.closest_m[0][res.evaluated[0].any(axis=1)] <= 0.0)


@SETTINGS
@given(cell())
def test_boxes_contain_capsules(c: dict) -> None:
    """The broad phase's boxes contain their capsules (sampled surface points)."""
    ends, radius = c["ends"], c["radius"]
    lo, hi = boxes_of(ends, radius)
    rng = np.random.default_rng(0)
    s = rng.random((32, 1, 1, 1))
    u = rng.normal(size=(32, 1, 1, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    pts = ends[None, :, :, 0] + s * (ends[None, :, :, 1] - ends[None, :, :, 0])
    pts = pts + u * radius[None, :, :, None]
    assert np.all(pts >= lo - 1e-12) and np.all(pts <= hi + 1e-12)


@SETTINGS
@given(cell())
def test_body_distance_is_the_smallest_capsule_distance(c: dict) -> None:
    """``body_distance`` (the shield's display minimum and the simulator's collision check)
    equals the brute-force minimum over all (body part, link) capsule pairs."""
    sk, half = REACH.skeleton, PARAMS.half_thickness_m
    y, ends, radius = c["y"][0], c["ends"][0], c["radius"][0]
    parts = y[sk.part_joints]
    brute = geo.capsule_distances(parts, half, ends, radius).min()
    got = body_distance(y, sk.part_joints, half, ends, radius)
    assert abs(got - brute) <= 1e-12
    y_nan = y.copy()
    y_nan[3, 1] = np.nan
    assert np.isnan(body_distance(y_nan, sk.part_joints, half, ends, radius))
