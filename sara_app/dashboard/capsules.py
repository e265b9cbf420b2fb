"""Many capsules in viser as batched instances: one open tube plus one hemisphere per end (the
unit meshes and instance poses of :mod:`sara_app.geometry.capsule_mesh`; tube and caps meet at
the rims without overlap, so translucent capsules have no doubled seams).

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
from sara_app.geometry.capsule_mesh import (
    capsule_arrays,
    capsule_instances,
    unit_hemisphere,
    unit_tube,
)

# ----------------------------------------------------------------------------------------------
# Instance math


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
