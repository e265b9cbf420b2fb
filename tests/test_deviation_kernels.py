"""The compiled joint deviations against their numpy expressions (the oracle), on random vectors
with NaN, infinities and signed zeros in any place."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sara_app.robot.deviation_kernels import max_abs, max_abs_diff


def _vector(rng: np.random.Generator, n: int) -> np.ndarray:
    a = rng.normal(scale=rng.choice([1e-6, 1.0, 1e3]), size=n)
    for _ in range(int(rng.integers(0, 3))):  # specials anywhere, sometimes none
        a[rng.integers(0, n)] = rng.choice([np.nan, np.inf, -np.inf, -0.0, 0.0])
    return a


def _same(got: float, want: float) -> bool:
    return (math.isnan(got) and math.isnan(want)) or got == want


def test_as_numpy_computes_them() -> None:
    rng = np.random.default_rng(3)
    nans = 0
    for _ in range(20000):
        n = int(rng.integers(1, 10))
        a, b = _vector(rng, n), _vector(rng, n)
        with np.errstate(invalid="ignore"):  # inf - inf, as numpy computes it
            want_diff = float(np.max(np.abs(a - b)))
        want_abs = float(np.max(np.abs(a)))
        assert _same(max_abs_diff(a, b), want_diff), (a, b)
        assert _same(max_abs(a), want_abs), a
        nans += math.isnan(want_diff)
    assert nans > 1000  # NaN in every position was tried, not only last


def test_nan_wins_wherever_it_stands() -> None:
    """A NaN after a larger entry still gives NaN (a `not x <= tol` check then fails safe)."""
    for k in range(4):
        a = np.array([5.0, 1.0, 2.0, 3.0])
        a[k] = np.nan
        assert math.isnan(max_abs(a))
        assert math.isnan(max_abs_diff(a, np.zeros(4)))
        assert math.isnan(max_abs_diff(np.zeros(4), a))


def test_any_real_dtype_and_empty_vectors() -> None:
    assert max_abs_diff([1, 2, 3], np.array([1, 5, 2], dtype=np.int32)) == 3.0
    assert max_abs(np.array([-4, 2], dtype=np.float32)) == 4.0
    assert max_abs_diff(np.zeros(0), np.zeros(0)) == 0.0 and max_abs(np.zeros(0)) == 0.0
    view = np.arange(12.0)[::3]  # not contiguous
    assert max_abs_diff(view, np.zeros(4)) == 9.0


def test_vectors_of_different_lengths_raise() -> None:
    with pytest.raises(ValueError, match="different lengths"):
        max_abs_diff(np.zeros(7), np.zeros(6))
    with pytest.raises(ValueError, match="different lengths"):
        max_abs_diff(np.zeros(7), np.zeros(1))  # numpy would broadcast this one
