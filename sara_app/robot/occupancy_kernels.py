"""Compiled (numba) kinematics of :class:`sara_app.robot.occupancy.RobotOccupancy`: joint frames
along the chain, capsule ends, and the Lipschitz interval capsules in one pass (formulas in that
module's docstring; checked against pinocchio when a ``RobotOccupancy`` is built, and against the
formula in ``tests/test_robot_occupancy.py``).

Explicit signatures (read-only ``'A'``-layout inputs) and ``cache=True``: compiled or loaded from
the cache at import, never in a control loop. The kernels call each other only within this file
(numba's cache does not notice changes in other files).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from sara_app.kernel_types import I8 as _i8
from sara_app.kernel_types import RO1 as _RO1
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import RO3 as _RO3
from sara_app.kernel_types import RO4 as _RO4
from sara_app.kernel_types import ROI1 as _ROI1
from sara_app.kernel_types import W2 as _W2
from sara_app.kernel_types import W4 as _W4

__all__ = ["ends_kernel", "fk_kernel", "intervals_kernel"]


@njit(types.void(_RO2, _RO3, _ROI1, _W4), cache=True)
def fk_kernel(Q: np.ndarray, N: np.ndarray, parents: np.ndarray, H: np.ndarray) -> None:
    """Joint frame poses: ``H[s, j+1] = H[s, parents[j]] @ (N0 + sin q N1 + (1 - cos q) N2)``
    for joint positions ``Q (S, n)`` (joint order), ``N (n, 3, 16)``; rows 0..2 of ``H (S, n+1,
    4, 4)`` are written (row 3 and ``H[:, 0]`` are the caller's)."""
    S, n = Q.shape
    hl = np.empty((3, 4))
    for s in range(S):
        for j in range(n):
            sq = math.sin(Q[s, j])
            cq = 1.0 - math.cos(Q[s, j])
            for r in range(3):
                for c in range(4):
                    x = 4 * r + c
                    hl[r, c] = N[j, 0, x] + sq * N[j, 1, x] + cq * N[j, 2, x]
            p = parents[j]
            for r in range(3):
                for c in range(4):
                    acc = H[s, p, r, 3] if c == 3 else 0.0
                    for m in range(3):
                        acc += H[s, p, r, m] * hl[m, c]
                    H[s, j + 1, r, c] = acc


@njit(types.void(_RO4, _ROI1, _RO3, _W4, _i8), cache=True)
def ends_kernel(
    H: np.ndarray, link_joint: np.ndarray, ends_joint: np.ndarray, E: np.ndarray, S: int
) -> None:
    """World capsule ends ``E[:S] (S, L, 2, 3)`` from joint poses ``H[:S] (S, n+1, 4, 4)``,
    the joint carrying each link ``link_joint (L,)`` and the ends in that joint's frame
    ``(L, 2, 3)``."""
    for s in range(S):
        for i in range(link_joint.shape[0]):
            m = link_joint[i]
            for e in range(2):
                for r in range(3):
                    E[s, i, e, r] = (
                        H[s, m, r, 0] * ends_joint[i, e, 0]
                        + H[s, m, r, 1] * ends_joint[i, e, 1]
                        + H[s, m, r, 2] * ends_joint[i, e, 2]
                        + H[s, m, r, 3]
                    )


@njit(
    _i8(_RO2, _RO2, _RO1, _RO3, _ROI1, _ROI1, _RO3, _RO2, _RO1, _W4, _W4, _W4, _W2),
    cache=True,
)
def intervals_kernel(
    Q: np.ndarray,
    V: np.ndarray,
    T: np.ndarray,
    N: np.ndarray,
    parents: np.ndarray,
    link_joint: np.ndarray,
    ends_joint: np.ndarray,
    lipschitz: np.ndarray,
    radius0: np.ndarray,
    H: np.ndarray,
    E: np.ndarray,
    ends: np.ndarray,
    radius: np.ndarray,
) -> int:
    """:meth:`RobotOccupancy.intervals` (Lipschitz bound) in one pass: checks the values (returns
    1 for a non-finite ``Q (K+1, n)``, 2 for non-finite or non-increasing times ``T (K+1,)``, 3
    for a non-finite or negative ``V (K, n)``, writing nothing else; 0 when valid), then fills
    ``H[:K+1]``, ``E[:K+1]`` (joint poses and capsule ends at the samples; buffers of at least
    ``K + 1`` samples), ``ends (K, L, 2, 3)`` (mid axes), ``radius (K, L) = dt / 2 * lipschitz
    @ V + radius0``."""
    S, n = Q.shape
    for s in range(S):
        for j in range(n):
            if not math.isfinite(Q[s, j]):
                return 1
        if not math.isfinite(T[s]) or (s > 0 and not T[s] > T[s - 1]):
            return 2
    for k in range(S - 1):
        for j in range(n):
            if not (math.isfinite(V[k, j]) and V[k, j] >= 0.0):
                return 3
    fk_kernel(Q, N, parents, H)
    ends_kernel(H, link_joint, ends_joint, E, S)
    L = link_joint.shape[0]
    for k in range(S - 1):
        half_dt = 0.5 * (T[k + 1] - T[k])
        for i in range(L):
            for e in range(2):
                for r in range(3):
                    ends[k, i, e, r] = 0.5 * (E[k, i, e, r] + E[k + 1, i, e, r])
            acc = 0.0
            for j in range(n):
                acc += lipschitz[i, j] * V[k, j]
            radius[k, i] = half_dt * acc + radius0[i]
    return 0
