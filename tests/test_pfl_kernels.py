"""The PFL verdict kernels (``sara_app.safety.pfl_kernels``) against numpy brute force: eq. 7's
threshold of every entry (the per-stack minimum shared between parts of one stack, and rows
that are not a partition computed on their own), on random classifications."""

from __future__ import annotations

import numpy as np

from sara_app.safety.pfl_kernels import entry_thresholds


def _brute(stack: np.ndarray, cls: np.ndarray, T_clamp: np.ndarray, T_free: np.ndarray):
    """``thr (K, L, P)``: T_free where cls < 2, else min over the stack of T_clamp (NaN
    skipped, inf when none)."""
    Tc = np.where(np.isnan(T_clamp), np.inf, T_clamp)  # (L, P)
    masked = np.where(stack[:, None, :, :], Tc[None, :, None, :], np.inf)  # (K, L, P, P)
    return np.where(cls < 2, T_free[None], masked.min(axis=-1))


def _partition(rng: np.random.Generator, K: int, P: int) -> np.ndarray:
    labels = rng.integers(0, rng.integers(1, P + 1), (K, P))
    return labels[:, :, None] == labels[:, None, :]


def test_entry_thresholds_equal_brute_force() -> None:
    rng = np.random.default_rng(4)
    shared = 0
    for trial in range(200):
        K, L, P = int(rng.integers(1, 6)), int(rng.integers(1, 10)), int(rng.integers(1, 16))
        if trial % 3 == 2:  # any boolean relation, not a partition
            stack = rng.random((K, P, P)) < 0.3
        else:
            stack = _partition(rng, K, P)
        cls = rng.integers(0, 4, (K, L, P)).astype(np.int8)
        T_clamp = rng.uniform(0.05, 2.0, (L, P))
        T_free = rng.uniform(0.05, 2.0, (L, P))
        if trial % 4 == 0:
            T_clamp[rng.random((L, P)) < 0.2] = np.nan
        thr = np.empty((K, L, P))
        entry_thresholds(stack, cls, T_clamp, T_free, thr)
        np.testing.assert_array_equal(thr, _brute(stack, cls, T_clamp, T_free))
        sizes = stack.sum(axis=-1)
        shared += int(((cls >= 2) & (sizes[:, None, :] > 1)).sum())
    assert shared > 1000  # stacks of several parts were exercised, not only singletons
