"""Compiled (numba) kernels of the Monte-Carlo volumes
(:func:`sara_app.geometry.shapes.union_volume_mc`, :func:`~sara_app.geometry.shapes.
effective_volume_mc`): how many sample points lie in a union of capsules, and in the
per-body-part intersection of several models' capsules.

``sara-app reach`` and ``volumes`` report each model's mean volume over 20 frames, 20 000
samples a set: in numpy every set built ``(samples, capsules, 3)`` temporaries, 5.3 s of the
5.7 s that ``sara-app reach`` took on a half-second recording (Intel Xeon VM, 2026-12-05).
Here each point is tested against the capsules one by one and stops at the first that holds
it, by :func:`sara_app.geometry.shape_kernels.point_segment_gap` (whose sums run in an order
of their own, so a point within a few ulps of a surface may be counted otherwise than numpy
counts it); ``tests/test_volume_kernels.py`` holds the numpy oracle.

Compiled with explicit signatures and ``cache=True`` at import, the callee's source digest in
their closure (see :mod:`sara_app.kernel_types`); called through numba's dispatcher (once per
set, not in a control loop).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit, types

from sara_app.geometry import shape_kernels
from sara_app.geometry.shape_kernels import point_segment_gap
from sara_app.kernel_types import RO1, RO2, RO3, RO4, source_digest

__all__ = ["effective_count", "union_count"]


@njit
def _inside(pts: np.ndarray, i: int, ends: np.ndarray, c: int, radius_m: float) -> bool:
    """Whether point ``pts[i]`` lies in capsule ``ends[c] (2, 3)`` of radius ``radius_m``
    (distance to the axis <= radius; NaN is not inside, as numpy's ``<=``). Not cached on its
    own: it calls another file's kernel (the caching rule)."""
    gap = point_segment_gap(
        pts[i, 0], pts[i, 1], pts[i, 2], ends[c, 0, 0], ends[c, 0, 1], ends[c, 0, 2],
        ends[c, 1, 0], ends[c, 1, 1], ends[c, 1, 2],
    )  # fmt: skip
    return gap <= radius_m


def _make_counts(geometry_source: str) -> tuple[Any, Any]:
    """Build :func:`union_count` and :func:`effective_count` with their callee's source digest
    in the closure."""

    @njit(types.int64(RO2, RO3, RO1), cache=True, nogil=True)
    def union_count(pts: np.ndarray, ends: np.ndarray, radius_m: np.ndarray) -> int:
        """How many points ``(S, 3)`` lie in at least one capsule ``ends (N, 2, 3)``, ``radius_m
        (N,)`` (:func:`~sara_app.geometry.shapes.points_in_union`, counted)."""
        if len(geometry_source) == 0:  # never: ties the cache to shape_kernels.py
            raise ValueError("no shape_kernels source digest")
        count = 0
        for i in range(pts.shape[0]):
            for c in range(ends.shape[0]):
                if _inside(pts, i, ends, c, radius_m[c]):
                    count += 1
                    break
        return count

    @njit(types.int64(RO2, RO4, RO2), cache=True, nogil=True)
    def effective_count(pts: np.ndarray, ends: np.ndarray, radius_m: np.ndarray) -> int:
        """How many points ``(S, 3)`` lie, for some body part ``p``, in capsule ``p`` of every
        model ``m``: ``ends (M, P, 2, 3)``, ``radius_m (M, P)`` (each model's capsule of each
        part)."""
        if len(geometry_source) == 0:  # never: ties the cache to shape_kernels.py
            raise ValueError("no shape_kernels source digest")
        M, P = ends.shape[0], ends.shape[1]
        count = 0
        for i in range(pts.shape[0]):
            for p in range(P):
                held = True
                for m in range(M):
                    if not _inside(pts, i, ends[m], p, radius_m[m, p]):
                        held = False
                        break
                if held:
                    count += 1
                    break
        return count

    return union_count, effective_count


union_count, effective_count = _make_counts(source_digest(shape_kernels))
