"""The containment analysis's compiled kernel (``sara_app.human.containment_kernels``) against
its numpy oracle: the per-model step of :func:`sara_app.human.analysis.containment` as numpy
wrote it (gathered arrays, ``point_segment_distance``, ``ufunc.at``), on random capsules and
joints with the cases that decide a verdict: points on and just off a capsule's surface, point
capsules, a joint several capsules must hold, non-finite radii (a model without a set) and
non-finite positions. The excesses agree to a few units in the last place (numpy's ``einsum``
adds its three products in an order of its own), the flags exactly except where the oracle's
excess is that close to the 1e-12 m tolerance."""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.geometry.shapes import point_segment_distance
from sara_app.human.containment_kernels import cover_joints


def _oracle(fut, ends, radius, cap, joint, margin):
    F, K, J = fut.shape[:3]
    d = point_segment_distance(fut[:, :, joint], ends[:, :, cap])  # (F, K, M)
    excess = d + margin - radius[:, :, cap]
    inside = np.ones((F, K, J), dtype=bool)
    np.logical_and.at(inside, (slice(None), slice(None), joint), excess <= 1e-12)
    worst = np.full((F, K, J), -np.inf)
    np.maximum.at(worst, (slice(None), slice(None), joint), excess)
    known = np.ones((F, K, J), dtype=bool)
    np.logical_and.at(known, (slice(None), slice(None), joint), np.isfinite(radius[:, :, cap]))
    return inside, worst, known


def _case(rng: np.random.Generator, F: int, K: int, J: int, C: int, M: int):
    ends = rng.normal(0.0, 0.5, (F, K, C, 2, 3))
    ends[:, :, 0, 1] = ends[:, :, 0, 0]  # a point capsule (a ball)
    radius = rng.uniform(0.05, 0.4, (F, K, C))
    cap = rng.integers(0, C, M)
    joint = np.concatenate([np.arange(J), rng.integers(0, J, M - J)])  # some joints twice
    margin = rng.uniform(0.0, 0.1, M)
    fut = rng.normal(0.0, 0.5, (F, K, J, 3))
    # some joints exactly on a capsule's axis end, some at its surface less the margin
    on = rng.random((F, K, M)) < 0.2
    for f, k, m in zip(*np.nonzero(on), strict=True):
        fut[f, k, joint[m]] = ends[f, k, cap[m], rng.integers(0, 2)]
        if rng.random() < 0.5:
            radius[f, k, cap[m]] = margin[m]
    radius[rng.random((F, K, C)) < 0.05] = np.inf
    radius[rng.random((F, K, C)) < 0.05] = np.nan
    fut[rng.random((F, K, J)) < 0.02] = np.nan
    return fut, ends, radius, cap, joint, margin


def _seeded(seed: int):
    """A case of random sizes (F, K, J, C at most 8; M up to 11 more than J)."""
    rng = np.random.default_rng(seed)
    F, K, J, C = (int(x) for x in rng.integers(1, 9, 4))
    return _case(rng, F, K, J, C, J + int(rng.integers(0, 12)))


@pytest.mark.parametrize("seed", range(6))
def test_the_kernel_equals_the_numpy_oracle(seed: int) -> None:
    fut, ends, radius, cap, joint, margin = _seeded(seed)
    F, K, J = fut.shape[:3]
    want = _oracle(fut, ends, radius, cap, joint, margin)
    got = (np.ones((F, K, J), bool), np.full((F, K, J), -np.inf), np.ones((F, K, J), bool))
    cover_joints(fut, ends, radius, cap, joint, margin, *got)
    np.testing.assert_array_equal(got[2], want[2], err_msg="known")
    np.testing.assert_allclose(got[1], want[1], rtol=4e-16, atol=4e-16, err_msg="worst")
    at_tolerance = np.abs(want[1] - 1e-12) <= 4e-16  # the excess decides within round-off
    np.testing.assert_array_equal(got[0] | at_tolerance, want[0] | at_tolerance, "inside")


def test_the_cases_that_decide_occur_in_the_random_data() -> None:
    """The oracle comparison above is not vacuous: its data hold joints inside and outside,
    NaN and infinite excesses and unknown joints."""
    seen = {"inside": 0, "outside": 0, "nan": 0, "unknown": 0}
    for seed in range(6):
        inside, worst, known = _oracle(*_seeded(seed))
        seen["inside"] += int(inside.sum())
        seen["outside"] += int((~inside).sum())
        seen["nan"] += int(np.isnan(worst).sum())
        seen["unknown"] += int((~known).sum())
    assert min(seen.values()) > 0, seen


def test_the_kernel_refuses_arrays_of_another_type() -> None:
    """Called through numba's dispatcher: float32 positions or float capsule indices are a
    TypeError, never read as another type."""
    rng = np.random.default_rng(0)
    fut, ends, radius, cap, joint, margin = _case(rng, 2, 2, 3, 2, 4)
    out = (np.ones((2, 2, 3), bool), np.full((2, 2, 3), -np.inf), np.ones((2, 2, 3), bool))
    with pytest.raises(TypeError):
        cover_joints(fut.astype(np.float32), ends, radius, cap, joint, margin, *out)
    with pytest.raises(TypeError):
        cover_joints(fut, ends, radius, cap.astype(float), joint, margin, *out)
