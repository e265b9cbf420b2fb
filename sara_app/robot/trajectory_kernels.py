"""Compiled (numba) sampling of a shielded trajectory: the path motion ``s(t)`` of one intended
step followed by its failsafe, the joint states along the path at the sample times, and the
rigorous per-interval bounds on joint speed and acceleration, in one pass.

The formulas are those of :class:`sara_app.robot.profile.ScalarProfile` (``evaluate``,
``interval_maxima``), :class:`~sara_app.robot.path.PathTrajectory` (quartic pieces,
``interval_bounds``) and ``sara_app.robot.failsafe._bounds_kernel``; ``sara_app.robot.shielded``
keeps the numpy composition of those as its reference, and ``tests/test_trajectory_kernels.py``
checks the two equal on random paths and states.

Explicit signatures and ``cache=True``: compiled or loaded from the cache at import, never in a
control loop. Helpers are called only within this file (numba's cache does not notice changes
in other files); constants from other modules are passed as arguments for the same reason.
"""

from __future__ import annotations

import numpy as np
from numba import njit, types

from sara_app.kernel_types import F8 as _f8
from sara_app.kernel_types import RO1 as _RO1
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import RO3 as _RO3
from sara_app.kernel_types import W1 as _W1
from sara_app.kernel_types import W2 as _W2
from sara_app.kernel_types import W3 as _W3

__all__ = ["shielded_samples_kernel"]


@njit(types.intp(_RO1, _f8), cache=True)
def _count_le(sorted_x: np.ndarray, x: float) -> int:
    """How many entries of ``sorted_x`` are ``<= x`` (``np.searchsorted(.., side='right')``)."""
    lo, hi = 0, sorted_x.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if sorted_x[mid] <= x:
            lo = mid + 1
        else:
            hi = mid
    return lo


_SAMPLES_SIG = types.void(
    *(_f8,) * 5, _RO1, _RO1, _RO1, _RO3, _RO2, _RO2, _RO2, _f8, _W1, _W2, _W3, _W3, _W1
)


@njit(_SAMPLES_SIG, cache=True)
def shielded_samples_kernel(
    dt: float,
    T: float,
    s0: float,
    v0: float,
    a0: float,
    phases: np.ndarray,
    piece_s0: np.ndarray,
    piece_len: np.ndarray,
    poly: np.ndarray,
    M1p: np.ndarray,
    M2p: np.ndarray,
    qs_start: np.ndarray,
    bound_pad: float,
    times: np.ndarray,
    path: np.ndarray,
    joint: np.ndarray,
    bounds: np.ndarray,
    sd_max: np.ndarray,
) -> None:
    """Fill the samples of one step of ``dt`` + a failsafe of ``T`` seconds.

    Path motion: from ``(s0, v0, a0)`` through ``phases (2 P,)``, ``P`` durations then their
    jerks (step then stop; zero jerk after). Path pieces ``(N,)``: starts ``piece_s0``,
    lengths ``piece_len``, quartic coefficients ``poly (N, 5, >= 3 n)`` of
    ``[q | dq/ds | d2q/ds2]`` in ``tau = s - s_k``, maxima ``M1p, M2p (N, n)`` of
    ``|dq/ds|``, ``|d2q/ds2|`` per piece, ``qs_start (N, n)`` = ``dq/ds`` at every piece start.
    ``bound_pad``: relative padding of the bounds.

    Writes ``times (K+1,)`` (0, ``dt``, then ``K-1`` equal failsafe intervals), ``path (3, K+1)``
    = ``s, s', s''``, ``joint (5, K+1, n)`` = ``q, dq/ds, d2q/ds2, v, a`` and ``bounds (2, K, n)``
    = rigorous ``max |v_j|``, ``max |a_j|`` over every interval, ``sd_max (K,)`` = the exact
    largest path speed ``s'`` over every interval.
    """
    P = phases.shape[0] // 2
    durs, jerks = phases[:P], phases[P:]
    m = times.shape[0] - 2
    K = m + 1
    n = M1p.shape[1]
    N = piece_s0.shape[0]
    # sample times
    times[0] = 0.0
    times[1] = dt
    for i in range(1, m + 1):
        times[i + 1] = dt + T * (i / m)
    # phase table (same operation order as ScalarProfile.__init__)
    tb = np.empty(P + 1)
    sb = np.empty(P + 1)
    vb = np.empty(P + 1)
    ab = np.empty(P + 1)
    s, v, a, t = s0, v0, a0, 0.0
    tb[0], sb[0], vb[0], ab[0] = t, s, v, a
    for i in range(P):
        d, j = durs[i], jerks[i]
        s += d * (v + d * (0.5 * a + d * j / 6.0))
        v += d * (a + 0.5 * d * j)
        a += d * j
        t += d
        tb[i + 1], sb[i + 1], vb[i + 1], ab[i + 1] = t, s, v, a
    # path motion at the samples
    for k in range(K + 1):
        tk = max(times[k], 0.0)
        i = min(_count_le(tb, tk) - 1, P)
        tau = tk - tb[i]
        j = jerks[i] if i < P else 0.0
        path[0, k] = sb[i] + tau * (vb[i] + tau * (0.5 * ab[i] + tau * j / 6.0))
        path[1, k] = vb[i] + tau * (ab[i] + 0.5 * tau * j)
        path[2, k] = ab[i] + tau * j
    # interval maxima of s' and |s''|: ends, phase breaks, and s'' = 0 inside a phase
    vmax = sd_max
    amax = np.empty(K)
    for k in range(K):
        vmax[k] = max(path[1, k], path[1, k + 1])
        amax[k] = max(abs(path[2, k]), abs(path[2, k + 1]))
    for i in range(P):
        j = jerks[i]
        if i > 0:
            k = _count_le(times, tb[i]) - 1
            if 0 <= k < K and abs(ab[i]) > amax[k]:
                amax[k] = abs(ab[i])
        if j != 0.0:
            tau = -ab[i] / j
            if 0.0 < tau < durs[i]:
                k = _count_le(times, tb[i] + tau) - 1
                val = vb[i] + tau * (ab[i] + 0.5 * tau * j)
                if 0 <= k < K and val > vmax[k]:
                    vmax[k] = val
    # joint states along the path: one quartic per piece
    piece = np.empty(K + 1, dtype=np.intp)
    for k in range(K + 1):
        p = min(max(_count_le(piece_s0, path[0, k]) - 1, 0), N - 1)
        piece[k] = p
        tau = min(max(path[0, k] - piece_s0[p], 0.0), piece_len[p])
        sd, sdd = path[1, k], path[2, k]
        for c in range(n):
            for r in range(3):
                col = r * n + c
                x = poly[p, 4, col]
                for e in range(3, -1, -1):
                    x = x * tau + poly[p, e, col]
                joint[r, k, c] = x
            joint[3, k, c] = joint[1, k, c] * sd
            joint[4, k, c] = joint[2, k, c] * (sd * sd) + joint[1, k, c] * sdd
    # per-interval bounds: |dq/ds| is monotone on a piece, extremes at ends and piece starts
    pad = 1.0 + bound_pad
    for k in range(K):
        p0, p1 = piece[k], piece[k + 1]
        vm = vmax[k]
        if vm < 0.0:  # NaN stays NaN
            vm = 0.0
        for c in range(n):
            D1 = max(abs(joint[1, k, c]), abs(joint[1, k + 1, c]))
            M1 = max(M1p[p0, c], M1p[p1, c])
            M2 = max(M2p[p0, c], M2p[p1, c])
            for p in range(p0 + 1, p1 + 1):
                D1 = max(D1, abs(qs_start[p, c]))
                M1 = max(M1, M1p[p, c])
                M2 = max(M2, M2p[p, c])
            bounds[0, k, c] = D1 * vm * pad + 1e-15
            bounds[1, k, c] = (M2 * (vm * vm) + M1 * amax[k]) * pad + 1e-15


def _warm_up() -> None:
    """First-call dispatch at import, not in a control loop."""
    one = np.ones(1)
    times = np.empty(3)
    shielded_samples_kernel(
        0.004, 0.01, 0.0, 1.0, 0.0, np.array([1.0, -1.0]), np.zeros(1), one, np.zeros((1, 5, 3)),
        np.ones((1, 1)), np.ones((1, 1)), np.ones((1, 1)), 1e-12,
        times, np.empty((3, 3)), np.empty((5, 3, 1)), np.empty((2, 2, 1)), np.empty(2),
    )  # fmt: skip


_warm_up()
