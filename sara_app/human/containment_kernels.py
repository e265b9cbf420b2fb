"""Compiled (numba) kernel of the containment analysis
(:func:`sara_app.human.analysis.containment`): which future joint positions one model's capsules
hold.

The analysis gathers, per model, every (frame, future offset, covering capsule) triple: for a
recording of a few thousand frames that is tens of millions of point-segment distances. In numpy
each step of the distance allocated an array of that size (the gathered joints and capsule ends
first); the loop below reads each point and capsule once and writes the three per-joint results
directly. The arithmetic is that of :func:`sara_app.geometry.shapes.point_segment_closest`
(sums of three products left to right; numpy's ``einsum`` adds them in an order of its own, so
an excess may differ from numpy's in its last bits); ``tests/test_containment_kernels.py`` holds
the numpy oracle.

Compiled with an explicit signature and ``cache=True`` at import (see
:mod:`sara_app.kernel_types`); called through numba's dispatcher, which checks the arguments'
types (the analysis calls it once per chunk and model, not in a control loop).
"""

from __future__ import annotations

import math

from numba import njit, types

from sara_app.kernel_types import RO1, RO3, RO4, RO5, ROI1, W3, WB3

__all__ = ["cover_joints"]


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
    F, K = fut.shape[0], fut.shape[1]
    for f in range(F):
        for k in range(K):
            for m in range(cap.shape[0]):
                c, j = cap[m], joint[m]
                ax, ay, az = ends[f, k, c, 0, 0], ends[f, k, c, 0, 1], ends[f, k, c, 0, 2]
                dx = ends[f, k, c, 1, 0] - ax
                dy = ends[f, k, c, 1, 1] - ay
                dz = ends[f, k, c, 1, 2] - az
                dd = dx * dx + dy * dy + dz * dz
                wx, wy, wz = fut[f, k, j, 0] - ax, fut[f, k, j, 1] - ay, fut[f, k, j, 2] - az
                s = (wx * dx + wy * dy + wz * dz) / (dd if dd > 0.0 else 1.0)
                if s < 0.0:  # a clip that keeps NaN, as np.clip
                    s = 0.0
                elif s > 1.0:
                    s = 1.0
                gx = fut[f, k, j, 0] - (ax + s * dx)
                gy = fut[f, k, j, 1] - (ay + s * dy)
                gz = fut[f, k, j, 2] - (az + s * dz)
                r = radius[f, k, c]
                e = (math.sqrt(gx * gx + gy * gy + gz * gz) + margin[m]) - r
                if not math.isfinite(r):
                    known[f, k, j] = False
                if not e <= 1e-12:
                    inside[f, k, j] = False
                w = worst[f, k, j]
                if math.isnan(w) or math.isnan(e):
                    worst[f, k, j] = math.nan
                elif e > w:
                    worst[f, k, j] = e
