"""Capsules as triangle meshes (numpy, no viewer): the unit tube and hemisphere every capsule
is drawn from, the instance poses that place them, and capsules cut by a horizontal plane.

A capsule ``(a, b, r)`` is

- the unit tube (radius 1, axis +z, ``z`` in ``[-0.5, 0.5]``, no end disks) at the midpoint of
  ``a b``, rotated so that +z points along ``d = (b - a) / L`` and scaled by ``(r, r, L)``;
- the unit upper hemisphere (radius 1, ``z >= 0``) at ``b`` rotated so that +z points along
  ``d``, and at ``a`` rotated so that +z points along ``-d``, both scaled by ``r``.

Tube and caps meet at the rims without overlap. A degenerate capsule (``L = 0``) gets a
zero-length tube and two hemispheres that close into a sphere. A capsule with a non-finite end
or radius, or a negative radius, is hidden (scale 0).

A capsule cut by a plane (:func:`cut_capsule_mesh`) is the set a height bound leaves of it: the
SSM check clears a leg part that an upper-body tracker does not measure of every link wholly
above the part's bound (:mod:`sara_app.human.legs`), so the set it relies on is the capsule
intersected with the half-space ``z <= below_m``: every triangle of the capsule's mesh clipped
against the plane, the cross-section closed by a lid. Drawn by the dashboard
(:mod:`sara_app.dashboard.cut_capsules`) and the ROS 2 markers (:mod:`sara_app.ros2.convert`).
"""

from __future__ import annotations

import functools

import numpy as np

from sara_app.errors import InputError
from sara_app.geometry.shapes import quat_rotate, quat_z_to

_Z = np.array([0.0, 0.0, 1.0])
_TINY = 1e-12


# ----------------------------------------------------------------------------------------------
# Unit meshes


def unit_tube(sections: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """Open unit tube: vertices ``(2 S, 3)`` (rim at z = -0.5 then z = +0.5), faces ``(2 S, 3)``.

    Faces are wound counter-clockwise seen from outside (outward normals).
    """
    ang = np.linspace(0.0, 2.0 * np.pi, sections, endpoint=False)
    ring = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    bottom = np.column_stack([ring, np.full(sections, -0.5)])
    top = np.column_stack([ring, np.full(sections, 0.5)])
    vertices = np.concatenate([bottom, top])
    i = np.arange(sections)
    j = (i + 1) % sections
    lower = np.stack([i, j, j + sections], axis=1)
    upper = np.stack([i, j + sections, i + sections], axis=1)
    return vertices, np.concatenate([lower, upper]).astype(np.uint32)


def unit_hemisphere(sections: int = 20, rings: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Upper unit hemisphere without its base disk: vertices ``(V, 3)``, faces ``(F, 3)``.

    Ring 0 is the equator (z = 0, the same ``sections`` points as the tube rims), the last vertex
    is the pole. Faces are wound counter-clockwise seen from outside.
    """
    elev = np.linspace(0.0, 0.5 * np.pi, rings + 1)[:-1]
    ang = np.linspace(0.0, 2.0 * np.pi, sections, endpoint=False)
    ce, se = np.cos(elev)[:, None], np.sin(elev)[:, None]
    rim = np.stack(
        [ce * np.cos(ang)[None], ce * np.sin(ang)[None], np.broadcast_to(se, (rings, sections))],
        axis=-1,
    ).reshape(-1, 3)
    vertices = np.concatenate([rim, [[0.0, 0.0, 1.0]]])
    i = np.arange(sections)
    j = (i + 1) % sections
    faces = []
    for k in range(rings - 1):
        lo, hi = k * sections, (k + 1) * sections
        faces.append(np.stack([lo + i, lo + j, hi + j], axis=1))
        faces.append(np.stack([lo + i, hi + j, hi + i], axis=1))
    top = (rings - 1) * sections
    pole = rings * sections
    faces.append(np.stack([top + i, top + j, np.full(sections, pole)], axis=1))
    return vertices, np.concatenate(faces).astype(np.uint32)


def unit_box() -> tuple[np.ndarray, np.ndarray]:
    """Unit cube ``[-0.5, 0.5]^3``: vertices ``(8, 3)``, faces ``(12, 3)`` wound outward."""
    v = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    faces = [(a, b, c) for a, b, c, _ in quads] + [(a, c, d) for a, _, c, d in quads]
    return v, np.array(faces, dtype=np.uint32)


# ----------------------------------------------------------------------------------------------
# Instance math


def capsule_instances(
    ends: np.ndarray,
    radius: np.ndarray,
    tube_pos: np.ndarray,
    tube_wxyz: np.ndarray,
    tube_scale: np.ndarray,
    cap_pos: np.ndarray,
    cap_wxyz: np.ndarray,
    cap_scale: np.ndarray,
) -> None:
    """Instance poses of ``N`` capsules ``ends (N, 2, 3)``, ``radius (N,)``, written in place.

    Outputs (first ``N`` / ``2 N`` rows are written): ``tube_pos (N, 3)``, ``tube_wxyz (N, 4)``,
    ``tube_scale (N, 3)`` = (r, r, L); caps interleaved per capsule (a then b):
    ``cap_pos (2 N, 3)``, ``cap_wxyz (2 N, 4)``, ``cap_scale (2 N,)`` = r. Invalid capsules
    (non-finite, negative radius) get scale 0 and position 0.
    """
    n = ends.shape[0]
    ok = np.isfinite(ends).all(axis=(1, 2)) & np.isfinite(radius) & (radius >= 0.0)
    e = np.where(ok[:, None, None], ends, 0.0)
    r = np.where(ok, radius, 0.0)
    axis = e[:, 1] - e[:, 0]
    length = np.linalg.norm(axis, axis=1)
    long = length > _TINY
    d = np.where(long[:, None], axis / np.where(long, length, 1.0)[:, None], _Z)
    q = quat_z_to(d)
    tube_pos[:n] = 0.5 * (e[:, 0] + e[:, 1])
    tube_wxyz[:n] = q
    tube_scale[:n, 0] = r
    tube_scale[:n, 1] = r
    tube_scale[:n, 2] = length
    cap_pos[: 2 * n] = e.reshape(-1, 3)
    caps = cap_wxyz[: 2 * n].reshape(n, 2, 4)
    caps[:, 1] = q
    # q (x) (0, 1, 0, 0): a half turn about the local x axis first, so +z goes to -d.
    caps[:, 0, 0] = -q[:, 1]
    caps[:, 0, 1] = q[:, 0]
    caps[:, 0, 2] = q[:, 3]
    caps[:, 0, 3] = -q[:, 2]
    cap_scale[: 2 * n] = np.repeat(r, 2)


def capsule_arrays(ends: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Checked float arrays ``ends (N, 2, 3)``, ``radius (N,)``; :class:`InputError` if not."""
    e = np.asarray(ends, dtype=float)
    r = np.asarray(radius, dtype=float)
    if e.ndim != 3 or e.shape[1:] != (2, 3):
        raise InputError(f"capsule ends have shape {e.shape}; expected (N, 2, 3)")
    if r.shape != (e.shape[0],):
        raise InputError(f"capsule radii have shape {r.shape}; expected ({e.shape[0]},)")
    return e, r


# ----------------------------------------------------------------------------------------------
# Capsules cut by a horizontal plane

SECTIONS, RINGS = 12, 4
"""Mesh resolution of a cut capsule (coarser than the instanced ones: it is sent as vertices)."""


@functools.lru_cache(maxsize=8)
def _unit_meshes(sections: int, rings: int) -> tuple[np.ndarray, ...]:
    """The unit tube's and hemisphere's vertices and faces, built once per resolution (the cut
    sets are meshed at the display's rate), read-only."""
    out = (*unit_tube(sections), *unit_hemisphere(sections, rings))
    for a in out:
        a.setflags(write=False)
    return out


def capsule_triangles(
    ends: np.ndarray, radius: np.ndarray, sections: int = SECTIONS, rings: int = RINGS
) -> np.ndarray:
    """World triangles ``(N, F, 3, 3)`` of ``N`` capsules ``ends (N, 2, 3)``, ``radius (N,)``:
    the tube's faces, then the hemisphere at ``a``'s, then ``b``'s; wound outward."""
    n = ends.shape[0]
    tube_v, tube_f, cap_v, cap_f = _unit_meshes(sections, rings)
    t_pos, t_q, t_s = np.zeros((n, 3)), np.zeros((n, 4)), np.zeros((n, 3))
    c_pos, c_q, c_s = np.zeros((2 * n, 3)), np.zeros((2 * n, 4)), np.zeros(2 * n)
    capsule_instances(ends, radius, t_pos, t_q, t_s, c_pos, c_q, c_s)
    tube = t_pos[:, None] + quat_rotate(t_q[:, None], tube_v[None] * t_s[:, None])
    caps = c_pos[:, None] + quat_rotate(c_q[:, None], cap_v[None] * c_s[:, None, None])
    caps = caps.reshape(n, 2, cap_v.shape[0], 3)
    return np.concatenate(
        [tube[:, tube_f], caps[:, 0][:, cap_f], caps[:, 1][:, cap_f]], axis=1
    )  # fmt: skip


def clip_below(tris: np.ndarray, z_cut: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Clip the closed convex meshes ``tris (N, F, 3, 3)`` to ``z <= z_cut (N,)``.

    Returns the kept triangles ``(T, 3, 3)``: those wholly below as they are, those crossing
    the plane clipped (a triangle cut by one plane is a polygon of three or four vertices,
    fanned into one or two triangles in its own winding); and the lids ``(U, 3, 3)``: per cut
    mesh, a fan from the centroid of its crossing points through them in counter-clockwise
    order seen from above (outward normal +z)."""
    n, f = tris.shape[:2]
    t = tris.reshape(n * f, 3, 3)
    c = np.repeat(z_cut, f)
    below = t[:, :, 2] <= c[:, None]  # an infinite cut: every vertex
    count = below.sum(axis=1)
    whole = t[count == 3]
    x = np.flatnonzero((count == 1) | (count == 2))  # crossing: finite cuts only
    t, c, below = t[x], c[x], below[x]
    s = t[:, :, 2] - c[:, None]
    poly = np.zeros((x.size, 6, 3))
    keep = np.zeros((x.size, 6), dtype=bool)
    for e in range(3):  # Sutherland-Hodgman against one plane, edge a -> b
        a, b, sa, sb = t[:, e], t[:, (e + 1) % 3], s[:, e], s[:, (e + 1) % 3]
        poly[:, 2 * e], keep[:, 2 * e] = a, below[:, e]
        cross = below[:, e] != below[:, (e + 1) % 3]
        p = a + (sa / np.where(cross, sa - sb, 1.0))[:, None] * (b - a)
        p[:, 2] = c
        poly[:, 2 * e + 1], keep[:, 2 * e + 1] = p, cross
    flat = poly[keep]  # each polygon's 3 or 4 vertices in order, polygon after polygon
    size = keep.sum(axis=1)
    first = np.cumsum(size) - size
    fans = [flat[first[:, None] + [0, 1, 2]], flat[first[size == 4, None] + [0, 2, 3]]]
    crossing = poly[:, 1::2][keep[:, 1::2]]  # two per crossing triangle, in the same order
    lids = _lids(crossing, np.repeat(np.repeat(np.arange(n), f)[x], 2), n)
    return np.concatenate([whole, *fans]), lids


def _lids(points: np.ndarray, owner: np.ndarray, n: int) -> np.ndarray:
    """Fans ``(U, 3, 3)`` over the crossing ``points (Q, 3)`` of each mesh (``owner (Q,)``
    in ``0 .. n - 1``): from their centroid, through them by angle, closed onto the first."""
    if not points.shape[0]:
        return np.zeros((0, 3, 3))
    per = np.bincount(owner, minlength=n).astype(float)
    centre = np.stack(
        [np.bincount(owner, points[:, i], minlength=n) for i in range(3)], axis=1
    ) / np.maximum(per, 1.0)[:, None]  # fmt: skip
    d = points - centre[owner]
    order = np.lexsort((np.arctan2(d[:, 1], d[:, 0]), owner))
    ring, who = points[order], owner[order]
    nxt = np.arange(ring.shape[0]) + 1
    last = np.append(who[1:] != who[:-1], True)  # the last point of each mesh
    starts = np.flatnonzero(np.insert(who[1:] != who[:-1], 0, True))
    nxt[last] = starts  # closes onto the mesh's first point
    return np.stack([centre[who], ring, ring[nxt]], axis=1)


def cut_capsule_mesh(
    ends: np.ndarray, radius: np.ndarray, below_m: np.ndarray,
    sections: int = SECTIONS, rings: int = RINGS,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """One mesh of capsules ``ends (N, 2, 3)``, ``radius (N,)`` each cut to ``z <=
    below_m (N,)`` (``inf``: whole): vertices ``(V, 3)`` float32 (each point once), faces
    ``(T, 3)`` uint32.
    Capsules with a non-finite end or radius, a negative radius or a NaN cut are left out."""
    e, r = capsule_arrays(ends, radius)
    z = np.asarray(below_m, dtype=float)
    if z.shape != r.shape:
        raise InputError(f"capsule cut heights have shape {z.shape}; expected {r.shape}")
    ok = np.isfinite(e).all(axis=(1, 2)) & np.isfinite(r) & (r >= 0.0) & ~np.isnan(z)
    if not ok.any():
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32)
    kept, lids = clip_below(capsule_triangles(e[ok], r[ok], sections, rings), z[ok])
    soup = np.ascontiguousarray(np.concatenate([kept, lids]), dtype=np.float32).reshape(-1, 3)
    # the soup repeats each mesh vertex about six times: shared, the mesh sent is 2.8x smaller
    # (one person's legs: 56 -> 20 kB per frame) for 0.5 ms more
    _, first, inverse = np.unique(
        soup.view(np.dtype((np.void, 12))).ravel(), return_index=True, return_inverse=True
    )
    return soup[first], inverse.reshape(-1, 3).astype(np.uint32)
