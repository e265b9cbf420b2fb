"""Capsules cut by a horizontal plane (sara_app.dashboard.cut_capsules): the mesh is the cut
set's surface, closed and outward, against a Monte-Carlo oracle of the set's volume."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from sara_app.dashboard.cut_capsules import cut_capsule_mesh
from sara_app.errors import InputError


def _mesh(v: np.ndarray, f: np.ndarray) -> trimesh.Trimesh:
    """The soup welded: duplicated points merged and the zero-area fan triangles dropped."""
    m = trimesh.Trimesh(v.astype(float), f, process=False)
    m.merge_vertices(digits_vertex=5)
    m.update_faces(m.nondegenerate_faces(height=1e-9))
    m.remove_unreferenced_vertices()
    return m


def _cut_volume(a: np.ndarray, b: np.ndarray, r: float, z: float, rng: np.random.Generator,
                n: int = 400_000) -> float:  # fmt: skip
    """Monte-Carlo volume of capsule ``(a, b, r)`` below ``z`` (oracle: point-segment distance)."""
    lo, hi = np.minimum(a, b) - r, np.maximum(a, b) + r
    p = rng.uniform(lo, hi, size=(n, 3))
    d = b - a
    t = np.clip((p - a) @ d / (d @ d), 0.0, 1.0)
    inside = (np.linalg.norm(p - (a + t[:, None] * d), axis=1) <= r) & (p[:, 2] <= z)
    return float(np.prod(hi - lo) * inside.mean())


@pytest.mark.parametrize("seed", range(6))
def test_a_cut_capsule_is_closed_outward_below_its_cut_with_the_cut_sets_volume(seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = rng.normal(size=3)
    b = a + 0.5 * rng.normal(size=3)
    r = float(rng.uniform(0.1, 0.5))
    z = float(rng.uniform(min(a[2], b[2]) - r, max(a[2], b[2]) + r))
    v, f = cut_capsule_mesh(np.array([[a, b]]), np.array([r]), np.array([z]), 48, 16)
    assert v[:, 2].max() <= z + 1e-6
    m = _mesh(v, f)
    assert m.is_watertight and m.is_winding_consistent
    want = _cut_volume(a, b, r, z, rng)
    assert m.volume == pytest.approx(want, rel=0.03, abs=2e-4)  # inscribed mesh, sampling


def test_whole_capsules_and_capsules_above_their_cut() -> None:
    """No cut (inf) or a cut above the capsule: the whole capsule, closed; a cut below it:
    nothing; invalid capsules (NaN end, negative radius, NaN cut) are left out."""
    a, b, r = np.array([0.0, 0.0, 1.0]), np.array([0.2, 0.1, 1.4]), 0.15
    whole = np.pi * r**2 * (np.linalg.norm(b - a) + 4.0 / 3.0 * r)
    ends = np.array([[a, b]] * 5)
    ends[3, 0, 0] = np.nan
    radius = np.array([r, r, r, r, -1.0])
    for z in (np.inf, 2.0):
        v, f = cut_capsule_mesh(ends[:1], radius[:1], np.array([z]), 48, 16)
        m = _mesh(v, f)
        assert m.is_watertight and m.volume == pytest.approx(whole, rel=0.01)
    v, f = cut_capsule_mesh(ends[:1], radius[:1], np.array([0.5]))
    assert v.shape == (0, 3) and f.shape == (0, 3)
    cut = np.array([np.inf, 0.5, np.nan, np.inf, np.inf])
    v, f = cut_capsule_mesh(ends, radius, cut)
    alone, _ = cut_capsule_mesh(ends[:1], radius[:1], cut[:1])
    np.testing.assert_array_equal(v, alone)  # only the first is drawn
    with pytest.raises(InputError, match="cut heights"):
        cut_capsule_mesh(ends, radius, np.zeros(4))
