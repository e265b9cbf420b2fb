"""The Monte-Carlo volumes' compiled counts (sara_app.geometry.volume_kernels) against their
numpy oracle (sara_app.geometry.shapes.point_segment_distance): random capsule sets with point
segments, zero radii and NaN among them, sample points around and inside them; the volumes
that ``sara-app reach`` and ``volumes`` print are those of the numpy computation."""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.geometry import shapes as geo
from sara_app.geometry.volume_kernels import effective_count, union_count


def _capsules(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    ends = rng.uniform(-0.5, 0.5, (n, 2, 3))
    ends[::4, 1] = ends[::4, 0]  # point segments (balls)
    radius = rng.uniform(0.0, 0.3, n)
    radius[1::7] = 0.0
    return ends, radius


def _points(rng: np.random.Generator, ends: np.ndarray, radius: np.ndarray, s: int) -> np.ndarray:
    """Points in a box around the capsules, and some on the axes of those with a radius (inside
    them by far: on the axis of a capsule of radius 0 a point lies on its surface, where the
    last bits of a distance decide)."""
    pts = rng.uniform(-0.9, 0.9, (s, 3))
    on_axis = rng.choice(np.flatnonzero(radius > 0.01), s // 10)
    t = rng.random((len(on_axis), 1))
    pts[: len(on_axis)] = ends[on_axis, 0] + t * (ends[on_axis, 1] - ends[on_axis, 0])
    return pts


@pytest.mark.parametrize("seed", range(6))
def test_the_union_count_is_numpys(seed: int) -> None:
    rng = np.random.default_rng(seed)
    ends, radius = _capsules(rng, 3 + 5 * seed)
    pts = _points(rng, ends, radius, 4000)
    want = int(geo.points_in_union(pts, ends, radius).sum())
    assert 0 < want < len(pts)  # both answers occur
    assert union_count(pts, ends, radius) == want


def test_nan_is_inside_nothing_and_no_capsule_holds_nothing() -> None:
    rng = np.random.default_rng(7)
    ends, radius = _capsules(rng, 5)
    pts = _points(rng, ends, radius, 500)
    bad_r, bad_e = radius.copy(), ends.copy()
    bad_r[0] = np.nan
    bad_e[1, 0, 0] = np.nan
    for e, r in ((bad_e, radius), (ends, bad_r)):
        assert union_count(pts, e, r) == int(geo.points_in_union(pts, e, r).sum())
    nan_pts = pts.copy()
    nan_pts[::3, 1] = np.nan
    assert union_count(nan_pts, ends, radius) == int(
        geo.points_in_union(nan_pts, ends, radius).sum()
    )
    assert union_count(pts, ends[:0], radius[:0]) == 0


def _effective_oracle(pts: np.ndarray, ends: np.ndarray, radius: np.ndarray) -> int:
    """The per-part intersection over models, then the union over parts, in numpy: ``ends (M,
    P, 2, 3)``, ``radius (M, P)``."""
    held = np.ones((len(pts), ends.shape[1]), dtype=bool)
    for m in range(ends.shape[0]):
        held &= geo.point_segment_distance(pts[:, None, :], ends[m][None]) <= radius[m][None]
    return int(held.any(axis=1).sum())


@pytest.mark.parametrize("seed", range(6))
def test_the_effective_count_is_numpys(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    M, P = 1 + seed % 3, 4 + seed
    base, radius = _capsules(rng, P)
    ends = base[None] + rng.normal(0.0, 0.05, (M, P, 2, 3))  # models' sets of the same parts
    radii = radius[None] * rng.uniform(0.8, 1.5, (M, P))
    pts = _points(rng, base, radius, 4000)
    want = _effective_oracle(pts, ends, radii)
    assert 0 < want < len(pts)
    assert effective_count(pts, ends, radii) == want


def test_the_volumes_are_the_numpy_computations() -> None:
    """``union_volume_mc`` and ``effective_volume_mc`` give the volumes their numpy forms give
    on the same samples (the same generator state)."""
    rng = np.random.default_rng(3)
    ends, radius = _capsules(rng, 14)
    vol, err = geo.union_volume_mc(ends, radius, 20_000, np.random.default_rng(1))
    lo = (ends.min(axis=1) - radius[:, None]).min(axis=0)
    hi = (ends.max(axis=1) + radius[:, None]).max(axis=0)
    pts = lo + np.random.default_rng(1).random((20_000, 3)) * (hi - lo)
    share = geo.points_in_union(pts, ends, radius).mean()
    assert vol == float(np.prod(hi - lo)) * share and err > 0
    maps = [np.arange(14), np.roll(np.arange(14), 1)]
    sets = [(ends, radius), (ends + 0.02, radius * 1.1)]
    vol, _ = geo.effective_volume_mc(sets, maps, 20_000, np.random.default_rng(2))
    lo = np.maximum(*[(e.min(axis=1) - r[:, None]).min(axis=0) for e, r in sets])
    hi = np.minimum(*[(e.max(axis=1) + r[:, None]).max(axis=0) for e, r in sets])
    pts = lo + np.random.default_rng(2).random((20_000, 3)) * (hi - lo)
    caps = np.stack([e[pm] for (e, _), pm in zip(sets, maps)])
    radii = np.stack([r[pm] for (_, r), pm in zip(sets, maps)])
    share = _effective_oracle(pts, caps, radii) / 20_000
    assert vol == float(np.prod(hi - lo)) * share
