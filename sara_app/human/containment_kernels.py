"""Compiled (numba) kernel of the containment analysis
(:func:`sara_app.human.analysis.containment`): which future joint positions one model's capsules
hold.

The analysis gathers, per model, every (frame, future offset, covering capsule) triple: for a
recording of a few thousand frames that is tens of millions of point-segment distances. In numpy
each step of the distance allocated an array of that size (the gathered joints and capsule ends
first); the loop below reads each point and capsule once and writes the three per-joint results
directly. The distance is :func:`sara_app.geometry.shape_kernels.point_segment_gap` (whose
sums run in an order of their own, so an excess may differ from numpy's in its last bits);
``tests/test_containment_kernels.py`` holds the numpy oracle.

Compiled with an explicit signature and ``cache=True`` at import, the callee's source digest
in its closure (see :mod:`sara_app.kernel_types`); called through numba's dispatcher, which
checks the arguments' types (the analysis calls it once per chunk and model, not in a control
loop).
"""

from __future__ import annotations

import math
from typing import Any

from numba import njit, types

from sara_app.geometry import shape_kernels
from sara_app.geometry.shape_kernels import point_segment_gap
from sara_app.kernel_types import RO1, RO3, RO4, RO5, ROI1, W3, WB3, source_digest

__all__ = ["cover_joints"]


def _make_cover_joints(geometry_source: str) -> Any:
    """Build :func:`cover_joints` with its callee's source digest in the closure."""

    @njit(types.void(RO4, RO5, RO3, ROI1, ROI1, RO1, WB3, W3, WB3), cache=True, nogil=True)
    def cover_joints(fut, ends, radius, cap, joint, margin, inside, worst, known):  # type: ignore[no-untyped-def]
        """For every frame ``f``, offset ``k`` and coverage entry ``m`` (capsule ``cap[m]`` must
        hold joint ``joint[m]`` grown by ``margin[m]``): the excess ``e`` = distance of the future
        joint ``fut[f, k, joint[m]]`` to the capsule's axis + ``margin[m]`` - its radius, and per
        joint ``j``: ``inside[f, k, j]`` stays True only while every ``e <= 1e-12`` (NaN is not
        inside), ``worst[f, k, j]`` becomes the largest ``e`` (NaN wins, as ``np.maximum``),
        ``known[f, k, j]`` stays True only while every radius is finite (a model without a set
        there). Shapes: ``fut (F, K, J, 3)``, ``ends (F, K, C, 2, 3)``, ``radius (F, K, C)``;
        ``cap``, ``joint``, ``margin (M,)``; ``inside``, ``worst``, ``known (F, K, J)``, updated
        in place (the caller starts them at True, -inf and True)."""
        if len(geometry_source) == 0:  # never: ties the cache to shape_kernels.py
            raise ValueError("no shape_kernels source digest")
        F, K = fut.shape[0], fut.shape[1]
        for f in range(F):
            for k in range(K):
                for m in range(cap.shape[0]):
                    c, j = cap[m], joint[m]
                    gap = point_segment_gap(
                        fut[f, k, j, 0], fut[f, k, j, 1], fut[f, k, j, 2],
                        ends[f, k, c, 0, 0], ends[f, k, c, 0, 1], ends[f, k, c, 0, 2],
                        ends[f, k, c, 1, 0], ends[f, k, c, 1, 1], ends[f, k, c, 1, 2],
                    )  # fmt: skip
                    r = radius[f, k, c]
                    e = (gap + margin[m]) - r
                    if not math.isfinite(r):
                        known[f, k, j] = False
                    if not e <= 1e-12:
                        inside[f, k, j] = False
                    w = worst[f, k, j]
                    if math.isnan(w) or math.isnan(e):
                        worst[f, k, j] = math.nan
                    elif e > w:
                        worst[f, k, j] = e

    return cover_joints


cover_joints = _make_cover_joints(source_digest(shape_kernels))
