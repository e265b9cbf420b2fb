"""Capsules cut by a horizontal plane in viser: one mesh per set, rebuilt for each frame
(:func:`~sara_app.geometry.capsule_mesh.cut_capsule_mesh`: the cut differs per capsule, so it
cannot be instanced) and sent when it changed."""

from __future__ import annotations

import numpy as np
import viser

from sara_app.geometry.capsule_mesh import capsule_arrays, cut_capsule_mesh


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
            return  # shown again: sent in full (hiding forgot what was sent)
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
