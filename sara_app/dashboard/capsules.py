"""Many capsules in viser as batched instances: one open tube plus one hemisphere per end.

A capsule ``(a, b, r)`` is drawn as

- the unit tube (radius 1, axis +z, ``z`` in ``[-0.5, 0.5]``, no end disks) at the midpoint of
  ``a b``, rotated so that +z points along ``d = (b - a) / L`` and scaled by ``(r, r, L)``;
- the unit upper hemisphere (radius 1, ``z >= 0``) at ``b`` rotated so that +z points along
  ``d``, and at ``a`` rotated so that +z points along ``-d``, both scaled by ``r``.

Tube and caps meet at the rims without overlap, so translucent capsules have no doubled seams. A
degenerate capsule (``L = 0``) gets a zero-length tube and two hemispheres that close into a
sphere. A capsule with a non-finite end or radius, or a negative radius, is hidden (scale 0).

One :class:`CapsuleGroup` is two batched mesh nodes with a fixed opacity (viser drops batches
whose per-instance opacities change every frame). Instance arrays live in buffers of a capacity
that grows by doubling; unused slots have scale 0. Updates assign the buffers to the handles;
call :meth:`CapsuleGroup.set` inside ``server.atomic()`` with the rest of a frame.
"""

from __future__ import annotations

import numpy as np
import viser
import viser.transforms

from sara_app.errors import InputError
from sara_app.geometry.shapes import quat_rotate, quat_z_to

__all__ = ["quat_rotate", "quat_z_to"]

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


def rotation_to_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(M, 4)`` (w, x, y, z) of rotation matrices ``R (M, 3, 3)``."""
    return np.asarray(viser.transforms.SO3.from_matrix(np.asarray(R, dtype=float)).wxyz)


# ----------------------------------------------------------------------------------------------
# viser nodes


class InstanceBatch:
    """One batched mesh node with reusable instance buffers; unused slots have scale 0.

    ``positions (cap, 3)``, ``wxyzs (cap, 4)``, ``scales (cap, 3)`` or ``(cap,)`` when
    ``uniform``, ``colors (cap, 3)`` uint8. Fill the first ``n`` rows, then :meth:`push(n)`.
    """

    def __init__(
        self,
        server: viser.ViserServer,
        name: str,
        mesh: tuple[np.ndarray, np.ndarray],
        opacity: float | None,
        capacity: int = 16,
        uniform: bool = False,
        color: tuple[int, int, int] = (90, 200, 255),
    ) -> None:
        self._server, self._name, self._mesh = server, name, mesh
        self._opacity, self._uniform, self._color = opacity, uniform, color
        self._visible = True
        self.handle: viser.BatchedMeshHandle | None = None
        self._allocate(max(int(capacity), 1))

    @property
    def capacity(self) -> int:
        return int(self.positions.shape[0])

    def _allocate(self, capacity: int) -> None:
        self.positions = np.zeros((capacity, 3), dtype=np.float32)
        self.wxyzs = np.zeros((capacity, 4), dtype=np.float32)
        self.wxyzs[:, 0] = 1.0
        shape = (capacity,) if self._uniform else (capacity, 3)
        self.scales = np.zeros(shape, dtype=np.float32)
        self.colors = np.empty((capacity, 3), dtype=np.uint8)
        self.colors[:] = self._color
        self._sent: dict[str, np.ndarray] = {}
        if self.handle is not None:
            self.handle.remove()
        vertices, faces = self._mesh
        translucent = self._opacity is not None and self._opacity < 1.0
        self.handle = self._server.scene.add_batched_meshes_simple(
            self._name,
            vertices.astype(np.float32),
            faces,
            batched_wxyzs=self.wxyzs,
            batched_positions=self.positions,
            batched_scales=self.scales,
            batched_colors=self.colors,
            opacity=self._opacity,
            lod="off",
            cast_shadow=not translucent,
            receive_shadow=not translucent,
            visible=self._visible,
        )

    def reserve(self, n: int) -> None:
        """Grow (doubling) so that ``n`` instances fit; re-creates the node when it grows."""
        if n > self.capacity:
            self._allocate(max(n, 2 * self.capacity))

    def push(self, n: int) -> None:
        """Hide slots ``n:`` and send the buffers that changed since the last push.

        (Comparing here costs a few us per array; a viser property assignment about 50 us.)
        """
        self.scales[n:] = 0.0
        h = self.handle
        if h is None:  # created in __init__
            raise InputError("capsule batch without its scene handle")
        for key, buf in (
            ("batched_positions", self.positions),
            ("batched_wxyzs", self.wxyzs),
            ("batched_scales", self.scales),
            ("batched_colors", self.colors),
        ):
            sent = self._sent.get(key)
            if sent is None or not np.array_equal(sent, buf):
                setattr(h, key, buf)
                self._sent[key] = buf.copy()

    @property
    def visible(self) -> bool:
        return self._visible

    @visible.setter
    def visible(self, value: bool) -> None:
        self._visible = bool(value)
        if self.handle is not None:
            self.handle.visible = self._visible


def capsule_arrays(ends: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Checked float arrays ``ends (N, 2, 3)``, ``radius (N,)``; :class:`InputError` if not."""
    e = np.asarray(ends, dtype=float)
    r = np.asarray(radius, dtype=float)
    if e.ndim != 3 or e.shape[1:] != (2, 3):
        raise InputError(f"capsule ends have shape {e.shape}; expected (N, 2, 3)")
    if r.shape != (e.shape[0],):
        raise InputError(f"capsule radii have shape {r.shape}; expected ({e.shape[0]},)")
    return e, r


class CapsuleGroup:
    """A set of capsules drawn as two batched nodes (tubes, caps) with one fixed opacity.

    ``name`` is the scene path prefix (``<name>/tubes``, ``<name>/caps``); ``opacity`` None or 1
    for opaque, else translucent (fixed for the node's lifetime).
    """

    def __init__(
        self,
        server: viser.ViserServer,
        name: str,
        opacity: float | None = None,
        capacity: int = 16,
        color: tuple[int, int, int] = (90, 200, 255),
        sections: int = 20,
    ) -> None:
        self.name = name
        self.color = np.array(color, dtype=np.uint8)
        self.tubes = InstanceBatch(server, f"{name}/tubes", unit_tube(sections), opacity, capacity)
        self.caps = InstanceBatch(
            server, f"{name}/caps", unit_hemisphere(sections), opacity, 2 * capacity, uniform=True
        )
        self.count = 0

    def set(
        self,
        ends: np.ndarray,
        radius: np.ndarray,
        colors: np.ndarray | None = None,
    ) -> None:
        """Show capsules ``ends (N, 2, 3)`` [m], ``radius (N,)`` [m], ``colors (N, 3)`` uint8.

        ``colors`` None uses the group's colour. Raises :class:`InputError` on bad shapes;
        non-finite capsules are hidden, never raised on.
        """
        e, r = capsule_arrays(ends, radius)
        if not self.visible:
            return  # hidden: nothing to send; the next update after showing it sends all
        n = e.shape[0]
        self.tubes.reserve(n)
        self.caps.reserve(2 * n)
        t, c = self.tubes, self.caps
        capsule_instances(e, r, t.positions, t.wxyzs, t.scales, c.positions, c.wxyzs, c.scales)
        rgb = self.color if colors is None else np.asarray(colors)
        if rgb.shape not in ((3,), (n, 3)):
            raise InputError(f"capsule colours have shape {rgb.shape}; expected (3,) or ({n}, 3)")
        t.colors[:n] = rgb
        c.colors[: 2 * n].reshape(n, 2, 3)[:] = rgb[..., None, :] if rgb.ndim == 2 else rgb
        t.push(n)
        c.push(2 * n)
        self.count = n

    @property
    def visible(self) -> bool:
        return self.tubes.visible

    @visible.setter
    def visible(self, value: bool) -> None:
        self.tubes.visible = value
        self.caps.visible = value
