"""Capsules cut by a horizontal plane, drawn as one mesh: the sets of legs an upper-body tracker
does not measure, as the verification uses them.

The SSM check clears a leg part of a link that lies wholly above the part's height bound
(:mod:`sara_app.human.legs`), so the set it relies on for that part is the model's capsule
intersected with the half-space ``z <= below_m``. A capsule with a finite ``below_m`` is drawn
as that intersection: every triangle of its mesh (the tube and two hemispheres of
:mod:`sara_app.dashboard.capsules`, placed in the world) clipped against the plane, and the
cross-section closed by a lid. Not instanced: the cut differs per capsule, so the mesh is built
in numpy for each frame and sent when it changed.
"""

from __future__ import annotations

import numpy as np
import viser

from sara_app.dashboard.capsules import (
    capsule_arrays,
    capsule_instances,
    quat_rotate,
    unit_hemisphere,
    unit_tube,
)
from sara_app.errors import InputError

SECTIONS, RINGS = 12, 4
"""Mesh resolution of a cut capsule (coarser than the instanced ones: it is sent as vertices)."""


def capsule_triangles(
    ends: np.ndarray, radius: np.ndarray, sections: int = SECTIONS, rings: int = RINGS
) -> np.ndarray:
    """World triangles ``(N, F, 3, 3)`` of ``N`` capsules ``ends (N, 2, 3)``, ``radius (N,)``:
    the tube's faces, then the hemisphere at ``a``'s, then ``b``'s; wound outward."""
    n = ends.shape[0]
    tube_v, tube_f = unit_tube(sections)
    cap_v, cap_f = unit_hemisphere(sections, rings)
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


class CutCapsules:
    """Cut capsules of one colour and opacity as one mesh node ``name``, re-added when the
    mesh changed (viser's meshes have no settable vertices); nothing is sent while hidden."""

    def __init__(
        self, server: viser.ViserServer, name: str, opacity: float | None,
        color: tuple[int, int, int],
    ) -> None:  # fmt: skip
        self._server, self.name, self._opacity, self._color = server, name, opacity, color
        self._handle: viser.BatchedMeshHandle | None = None
        self._shown: np.ndarray | None = None
        self._visible = True
        self.count = 0

    def set(self, ends: np.ndarray, radius: np.ndarray, below_m: np.ndarray) -> None:
        """Show capsules ``ends (N, 2, 3)``, ``radius (N,)`` [m] cut at ``below_m (N,)`` [m]."""
        if not self._visible:
            capsule_arrays(ends, radius)  # bad shapes raise, shown or not
            self._shown = None  # shown again: sent in full
            return
        vertices, faces = cut_capsule_mesh(ends, radius, below_m)
        self.count = int(np.asarray(radius).shape[0])
        if self._shown is not None and np.array_equal(self._shown, vertices):
            return
        self._shown = vertices
        if not faces.shape[0]:
            if self._handle is not None:
                self._handle.remove()
                self._handle = None
            return
        translucent = self._opacity is not None and self._opacity < 1.0
        # one instance of a batched mesh: shaded as the instanced capsules beside it (a plain
        # mesh of the same colour rendered in another tone)
        self._handle = self._server.scene.add_batched_meshes_simple(
            self.name, vertices, faces, np.array([[1.0, 0.0, 0.0, 0.0]], np.float32),
            np.zeros((1, 3), np.float32), batched_scales=np.ones(1, np.float32),
            batched_colors=np.array([self._color], np.uint8), opacity=self._opacity,
            lod="off", cast_shadow=not translucent, receive_shadow=not translucent,
        )  # fmt: skip

    @property
    def vertices(self) -> np.ndarray:
        """``(V, 3)``: the mesh last sent (empty when none)."""
        return np.zeros((0, 3), np.float32) if self._shown is None else self._shown

    @property
    def visible(self) -> bool:
        return self._visible

    @visible.setter
    def visible(self, value: bool) -> None:
        self._visible = bool(value)
        if self._handle is not None:
            self._handle.visible = self._visible
        if not self._visible:
            self._shown = None
