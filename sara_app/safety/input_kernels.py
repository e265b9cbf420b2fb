"""The shield's checks of one person's arrays in one compiled call (``Shield._check_humans``):
three numpy reductions per person and cycle before (about 3 us in a warm loop, several times
that live). The numpy version is the oracle in ``tests/test_input_kernels.py``."""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from sara_app.kernel_types import RO1, RO2

__all__ = ["BAD_BOUND", "NON_FINITE", "human_values"]

NON_FINITE, BAD_BOUND = 1, 2
"""Codes: a joint position or velocity is NaN or infinite / a velocity error bound is negative
or NaN (0: good)."""


@njit(types.int64(RO2, RO2, RO1), cache=True)
def human_values(y: np.ndarray, v: np.ndarray, dv: np.ndarray) -> int:
    """The code of a person's joints ``y (J, 3)``, velocities ``v (J, 3)`` and their error
    bounds ``dv (J,)`` (shapes checked by the caller)."""
    for j in range(y.shape[0]):
        for c in range(3):
            if not (math.isfinite(y[j, c]) and math.isfinite(v[j, c])):
                return NON_FINITE
    for j in range(dv.shape[0]):
        if not dv[j] >= 0.0:
            return BAD_BOUND
    return 0
