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

    Returns the kept triangles ``(T, 3, 3)`` (each triangle clipped by one plane is a polygon of
    at most four vertices, fanned into one or two triangles in its own winding) and the lids
    ``(U, 3, 3)``: per cut mesh, a fan from the centroid of its crossing points through them in
    counter-clockwise order seen from above (outward normal +z)."""
    n, f = tris.shape[:2]
    t = tris.reshape(n * f, 3, 3)
    c = np.repeat(z_cut, f)
    s = t[:, :, 2] - np.where(np.isinf(c), 0.0, c)[:, None]  # (T, 3) height over the plane
    s[np.isposinf(c)] = -1.0  # no cut: every vertex inside (and no inf - inf)
    inside = s <= 0.0
    poly = np.zeros((n * f, 6, 3))
    keep = np.zeros((n * f, 6), dtype=bool)
    for e in range(3):  # Sutherland-Hodgman against one plane, edge a -> b
        a, b = t[:, e], t[:, (e + 1) % 3]
        sa, sb = s[:, e], s[:, (e + 1) % 3]
        poly[:, 2 * e], keep[:, 2 * e] = a, inside[:, e]
        cross = inside[:, e] != inside[:, (e + 1) % 3]
        w = np.divide(sa, sa - sb, out=np.zeros(n * f), where=cross)
        p = a + w[:, None] * (b - a)
        p[:, 2] = np.where(cross, c, p[:, 2])
        poly[:, 2 * e + 1], keep[:, 2 * e + 1] = p, cross
    lids = _lids(poly[:, 1::2].reshape(n, -1, 3), keep[:, 1::2].reshape(n, -1))
    order = np.argsort(~keep, axis=1, kind="stable")
    poly = np.take_along_axis(poly, order[:, :, None], axis=1)
    count = keep.sum(axis=1)
    kept = np.concatenate(
        [poly[count >= 3][:, [0, 1, 2]], poly[count == 4][:, [0, 2, 3]]]
    )  # fmt: skip
    return kept, lids


def _lids(points: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Fans ``(U, 3, 3)`` over each mesh's crossing ``points (N, Q, 3)`` (``valid (N, Q)``)."""
    has = valid.sum(axis=1) >= 3
    points, valid = points[has], valid[has]
    if not points.shape[0]:
        return np.zeros((0, 3, 3))
    count = valid.sum(axis=1)
    centre = (points * valid[..., None]).sum(axis=1) / count[:, None]
    d = points - centre[:, None]
    angle = np.where(valid, np.arctan2(d[..., 1], d[..., 0]), np.inf)
    order = np.argsort(angle, axis=1, kind="stable")
    ring = np.take_along_axis(points, order[..., None], axis=1)
    nxt = np.roll(ring, -1, axis=1)
    rows = np.arange(ring.shape[0])
    nxt[rows, count - 1] = ring[:, 0]  # the last crossing point closes onto the first
    used = np.arange(ring.shape[1])[None] < count[:, None]
    fan = np.stack([np.broadcast_to(centre[:, None], ring.shape), ring, nxt], axis=2)
    return fan[used]


def cut_capsule_mesh(
    ends: np.ndarray, radius: np.ndarray, below_m: np.ndarray,
    sections: int = SECTIONS, rings: int = RINGS,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """One triangle soup of capsules ``ends (N, 2, 3)``, ``radius (N,)`` each cut to ``z <=
    below_m (N,)`` (``inf``: whole): vertices ``(3 T, 3)`` float32, faces ``(T, 3)`` uint32.
    Capsules with a non-finite end or radius, a negative radius or a NaN cut are left out."""
    e, r = capsule_arrays(ends, radius)
    z = np.asarray(below_m, dtype=float)
    if z.shape != r.shape:
        raise InputError(f"capsule cut heights have shape {z.shape}; expected {r.shape}")
    ok = np.isfinite(e).all(axis=(1, 2)) & np.isfinite(r) & (r >= 0.0) & ~np.isnan(z)
    if not ok.any():
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint32)
    kept, lids = clip_below(capsule_triangles(e[ok], r[ok], sections, rings), z[ok])
    soup = np.concatenate([kept, lids]).astype(np.float32)
    return soup.reshape(-1, 3), np.arange(3 * soup.shape[0], dtype=np.uint32).reshape(-1, 3)


class CutCapsules:
    """Cut capsules of one colour and opacity as one mesh node ``name``, re-added when the
    mesh changed (viser's meshes have no settable vertices); nothing is sent while hidden."""

    def __init__(
        self, server: viser.ViserServer, name: str, opacity: float | None,
        color: tuple[int, int, int],
    ) -> None:  # fmt: skip
        self._server, self.name, self._opacity, self._color = server, name, opacity, color
        self._handle: viser.MeshHandle | None = None
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
        self._handle = self._server.scene.add_mesh_simple(
            self.name, vertices, faces, color=self._color, opacity=self._opacity,
            cast_shadow=not translucent, receive_shadow=not translucent,
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
