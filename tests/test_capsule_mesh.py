"""Capsules as meshes (sara_app.geometry.capsule_mesh): the transformed unit meshes lie exactly
on the capsule surface, the tube spans exactly the segment, caps close the right ends; mesh
winding; a capsule cut by a horizontal plane is the cut set's surface, closed and outward,
against a Monte-Carlo oracle of the set's volume."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from sara_app.dashboard.capsules import rotation_to_wxyz
from sara_app.errors import InputError
from sara_app.geometry.capsule_mesh import (
    capsule_instances,
    cut_capsule_mesh,
    unit_box,
    unit_hemisphere,
    unit_tube,
)
from sara_app.geometry.shapes import point_segment_distance, quat_rotate, quat_z_to

TUBE = unit_tube(16)
HEMI = unit_hemisphere(16, 5)
TOL = 1e-9


def _instances(ends: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, ...]:
    n = ends.shape[0]
    out = (
        np.zeros((n, 3)),
        np.zeros((n, 4)),
        np.zeros((n, 3)),
        np.zeros((2 * n, 3)),
        np.zeros((2 * n, 4)),
        np.zeros(2 * n),
    )
    capsule_instances(ends, radius, *out)
    return out


def _place(v: np.ndarray, pos: np.ndarray, wxyz: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """Mesh vertices ``v (V, 3)`` under each instance: ``(N, V, 3)`` = R diag(s) v + p."""
    s = scale[:, None, :] if scale.ndim == 2 else scale[:, None, None]
    return pos[:, None] + quat_rotate(wxyz[:, None], v[None] * s)


def _check_capsules(ends: np.ndarray, radius: np.ndarray) -> None:
    tp, tq, ts, cp, cq, cs = _instances(ends, radius)
    n = ends.shape[0]
    scale_tol = TOL * (1.0 + np.abs(ends).max())
    np.testing.assert_allclose(np.linalg.norm(tq, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(cq, axis=1), 1.0, atol=1e-12)
    # Tube: axis end points map exactly onto a and b; every vertex is at distance r from the
    # segment and its projection covers exactly [0, L].
    axis_pts = _place(np.array([[0.0, 0, -0.5], [0.0, 0, 0.5]]), tp, tq, ts)
    np.testing.assert_allclose(axis_pts, ends, atol=scale_tol)
    tube = _place(TUBE[0], tp, tq, ts)
    dist = point_segment_distance(tube, ends[:, None])
    np.testing.assert_allclose(dist, np.broadcast_to(radius[:, None], dist.shape), atol=scale_tol)
    d = ends[:, 1] - ends[:, 0]
    length = np.linalg.norm(d, axis=1)
    long = length > 1e-9  # shorter: a sphere, the drawn axis direction is arbitrary
    u = d[long] / length[long, None]
    proj = np.einsum("nvk,nk->nv", tube[long] - ends[long, None, 0], u)
    np.testing.assert_allclose(proj.min(axis=1), 0.0, atol=scale_tol)
    np.testing.assert_allclose(proj.max(axis=1), length[long], atol=scale_tol)
    # Caps: on the sphere of radius r around their end, on the outer side; poles at a - r d and
    # b + r d.
    caps = _place(HEMI[0], cp, cq, cs).reshape(n, 2, -1, 3)
    for k, sign in ((0, -1.0), (1, 1.0)):
        rel = caps[:, k] - ends[:, k, None]
        np.testing.assert_allclose(
            np.linalg.norm(rel, axis=-1),
            np.broadcast_to(radius[:, None], rel.shape[:2]),
            atol=scale_tol,
        )
        if long.any():
            along = sign * np.einsum("nvk,nk->nv", rel[long], u)
            assert along.min() >= -scale_tol
            np.testing.assert_allclose(rel[long, -1], sign * radius[long, None] * u, atol=scale_tol)


finite = st.floats(-3.0, 3.0, allow_nan=False, allow_infinity=False)


@settings(max_examples=60, deadline=None)
@given(
    arrays(np.float64, (5, 2, 3), elements=finite),
    arrays(np.float64, (5,), elements=st.floats(0.0, 0.5, allow_nan=False)),
)
def test_instances_span_capsule_surface(ends: np.ndarray, radius: np.ndarray) -> None:
    _check_capsules(ends, radius)


def test_long_capsule_pointing_almost_straight_down() -> None:
    """The counterexample hypothesis found in CI (session 8): 1 + d_z cancelled to a few ulps,
    the tube's end was 3.8e-9 m off for a 2.75 m capsule tilted 4e-8 rad from -z."""
    ends = np.full((5, 2, 3), -2.75)
    ends[3] = [[-2.75, 0.0, 0.0], [-2.75, 2.0**-23, -2.75]]
    _check_capsules(ends, np.zeros(5))
    for tilt in (1e-13, 1e-10, 1e-7, 1e-4):
        one = np.array([[[0.5, -1.0, 2.9], [0.5 + 3.0 * tilt, -1.0 - 2.0 * tilt, -2.9]]])
        _check_capsules(one, np.array([0.2]))


def test_capsule_pointing_down_with_a_subnormal_tilt() -> None:
    """The counterexample hypothesis found (session 11): a tilt of 1e-161 from -z, whose
    squares are subnormal, gave a quaternion of norm 1.005."""
    ends = np.zeros((5, 2, 3))
    ends[2] = [[1.11701239e-161, 0.0, 0.0], [0.0, 0.0, -1.0]]
    _check_capsules(ends, np.zeros(5))


def test_axis_aligned_and_antiparallel_and_nearly_antiparallel() -> None:
    a = np.array([0.3, -0.2, 0.5])
    dirs = np.array(
        [[0, 0, 1.0], [0, 0, -1.0], [1e-9, 0, -1.0], [1e-5, -2e-5, -1.0], [1.0, 0, 0], [0, 1, 0]]
    )
    ends = np.stack([np.broadcast_to(a, dirs.shape), a + 0.7 * dirs], axis=1)
    _check_capsules(ends, np.full(len(dirs), 0.1))


def test_quat_z_to_maps_z_onto_direction() -> None:
    rng = np.random.default_rng(1)
    d = rng.normal(size=(500, 3))
    d[:3] = [[0, 0, -1], [0, 0, 1], [1e-12, 0, -1]]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    q = quat_z_to(d)
    np.testing.assert_allclose(quat_rotate(q, np.broadcast_to([0, 0, 1.0], d.shape)), d, atol=1e-9)


def test_degenerate_capsule_is_a_sphere() -> None:
    ends = np.array([[[0.1, 0.2, 0.3], [0.1, 0.2, 0.3]]])
    tp, tq, ts, cp, cq, cs = _instances(ends, np.array([0.2]))
    assert ts[0, 2] == 0.0
    caps = _place(HEMI[0], cp, cq, cs)
    rel = caps - ends[0, 0]
    np.testing.assert_allclose(np.linalg.norm(rel, axis=-1), 0.2, atol=1e-12)
    # The two hemispheres face opposite ways: together they cover both poles of the sphere.
    np.testing.assert_allclose(rel[0, -1] + rel[1, -1], 0.0, atol=1e-12)
    assert np.linalg.norm(rel[0, -1]) == pytest.approx(0.2)


def test_invalid_capsules_are_hidden() -> None:
    ends = np.zeros((3, 2, 3))
    ends[:, 1, 2] = 1.0
    ends[0, 0, 0] = np.nan
    radius = np.array([0.1, -0.1, np.inf])
    tp, tq, ts, cp, cq, cs = _instances(ends, radius)
    assert np.all(ts == 0.0) and np.all(cs == 0.0)
    assert np.all(np.isfinite(tp)) and np.all(np.isfinite(tq)) and np.all(np.isfinite(cq))


@pytest.mark.parametrize("mesh", [TUBE, HEMI, unit_box()], ids=["tube", "hemisphere", "box"])
def test_meshes_wound_outward(mesh: tuple[np.ndarray, np.ndarray]) -> None:
    v, f = mesh
    tri = v[f.astype(int)]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    centroid = tri.mean(axis=1)
    centroid[:, 2] *= 0.0 if mesh is TUBE else 1.0  # a tube's outward direction is radial
    assert np.all(np.einsum("fk,fk->f", normal, centroid) > 0.0)
    assert np.all(np.linalg.norm(normal, axis=1) > 1e-6)  # no degenerate faces


def test_hemisphere_rim_matches_tube_rim() -> None:
    rim = HEMI[0][:16]
    np.testing.assert_allclose(rim[:, :2], TUBE[0][16:, :2], atol=1e-15)
    assert np.all(rim[:, 2] == 0.0)


def test_rotation_to_wxyz_round_trip() -> None:
    rng = np.random.default_rng(2)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    eye = np.eye(3)
    R = np.stack([quat_rotate(q, np.broadcast_to(e, (200, 3))) for e in eye], axis=2)
    q2 = rotation_to_wxyz(R)
    R2 = np.stack([quat_rotate(q2, np.broadcast_to(e, (200, 3))) for e in eye], axis=2)
    np.testing.assert_allclose(R2, R, atol=1e-9)


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
