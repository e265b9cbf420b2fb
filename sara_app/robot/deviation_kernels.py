"""How far two joint vectors are apart, ``max_j |a_j - b_j|``, and how large one is,
``max_j |a_j|``, in one compiled call each.

The measured robot's checks take these per robot state and cycle (tracking against the commanded
position and its slack, standing still, moved by hand): a numpy reduction each cost about 3 us
warm for seven joints, several times that in a loop that sleeps between cycles, against 0.2 us
here. NaN in any entry gives NaN, as numpy's ``max`` does (so a ``not x <= tol`` test fails
safe); vectors of different lengths raise ``ValueError`` (numpy raised where it could not
broadcast them). The numpy expressions are the oracle in ``tests/test_deviation_kernels.py``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

from sara_app.kernel_types import RO1, as_f8

__all__ = ["max_abs", "max_abs_diff"]


def max_abs_diff(a: Any, b: Any) -> float:
    """``max_j |a_j - b_j|`` of joint vectors ``a, b (n,)``, any real dtype."""
    return _max_abs_diff(as_f8(a), as_f8(b))  # type: ignore[no-any-return]


def max_abs(a: Any) -> float:
    """``max_j |a_j|`` of a joint vector ``a (n,)``, any real dtype."""
    return _max_abs(as_f8(a))  # type: ignore[no-any-return]


@njit(types.float64(RO1, RO1), cache=True)
def _max_abs_diff(a: np.ndarray, b: np.ndarray) -> float:
    """``max_j |a_j - b_j|`` of ``a, b (n,)`` (0 for ``n = 0``; NaN if any difference is)."""
    if a.shape[0] != b.shape[0]:
        raise ValueError("joint vectors of different lengths")
    m = 0.0
    for j in range(a.shape[0]):
        d = abs(a[j] - b[j])
        if not d <= m:
            if d != d:
                return math.nan
            m = d
    return m


@njit(types.float64(RO1), cache=True)
def _max_abs(a: np.ndarray) -> float:
    """``max_j |a_j|`` of ``a (n,)`` (0 for ``n = 0``; NaN if any entry is)."""
    m = 0.0
    for j in range(a.shape[0]):
        d = abs(a[j])
        if not d <= m:
            if d != d:
                return math.nan
            m = d
    return m
