"""Closest points of segment pairs and of segments and boxes in plain numpy,
structure-of-arrays layout (coordinates as the LEADING axis, ``(3, ...)``, every dot and cross
product written out per component): the independent references of the compiled geometry of
:mod:`sara_app.geometry.shape_kernels` (``set_pair_distances``, the segment-box closest points),
with the same mathematics as :func:`sara_app.geometry.shapes.segment_segment_closest` and
:func:`sara_app.geometry.shapes.segment_box_distance`. They were the PFL hot path before it was
compiled."""

from __future__ import annotations

import numpy as np

_PARALLEL_SIN2 = 1e-24  # as in sara_app.geometry.shapes


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _cross(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def segment_pairs_soa(
    p1: np.ndarray, q1: np.ndarray, p2: np.ndarray, q2: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of segments ``[p1, q1]`` and ``[p2, q2]``, each ``(3, ...)``.

    Returns ``(distance, s, t)`` ``(...)``: parameters in [0, 1] on the first and second segment.
    Degenerate (point) and parallel segments are handled as in :mod:`sara_app.geometry.shapes`.
    """
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e = _dot(d1, d1), _dot(d2, d2)
    b, c, f = _dot(d1, d2), _dot(d1, r), _dot(d2, r)
    a_pos, e_pos = a > 0.0, e > 0.0
    a_safe, e_safe = np.where(a_pos, a, 1.0), np.where(e_pos, e, 1.0)
    n = _cross(d1, d2)
    denom = n[0] * n[0] + n[1] * n[1] + n[2] * n[2]
    m = _cross(d2, r)
    general = denom > _PARALLEL_SIN2 * a * e
    s = np.where(
        general, (n[0] * m[0] + n[1] * m[1] + n[2] * m[2]) / np.where(general, denom, 1.0), 0.0
    )
    s = np.clip(np.where(a_pos, s, 0.0), 0.0, 1.0)
    t = np.where(e_pos, (b * s + f) / e_safe, -1.0)
    t_c = np.clip(t, 0.0, 1.0)
    s = np.where(t != t_c, np.where(a_pos, np.clip((b * t_c - c) / a_safe, 0.0, 1.0), 0.0), s)
    gap = r + s * d1 - t_c * d2  # (p1 + s d1) - (p2 + t d2)
    return np.sqrt(_dot(gap, gap)), s, t_c


def all_pairs(caps: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Segment distances and closest-point parameters of all pairs ``(K, N, N)`` of capsule
    axes ``(K, N, 2, 3)``, computed once per unordered pair; ``s[k, a, b]`` is the parameter on
    ``a`` of its closest point to ``b`` (``t = s`` transposed). The diagonal is 0."""
    K, N = caps.shape[:2]
    iu, ju = np.triu_indices(N, 1)
    soa = np.ascontiguousarray(caps.transpose(2, 3, 0, 1))  # (2, 3, K, N)
    a, b = np.take(soa, iu, axis=3), np.take(soa, ju, axis=3)  # contiguous (2, 3, K, pairs)
    d_p, s_p, t_p = segment_pairs_soa(a[0], a[1], b[0], b[1])
    d = np.zeros((K, N, N))
    s = np.zeros((K, N, N))
    d[:, iu, ju] = d_p
    d[:, ju, iu] = d_p
    s[:, iu, ju] = s_p
    s[:, ju, iu] = t_p
    return d, s, s.transpose(0, 2, 1)


def segment_box_soa(
    p: np.ndarray, q: np.ndarray, T_world_box: np.ndarray, half_extents_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of segments ``[p, q]`` ``(3, M)`` and ONE solid box ``(4, 4), (3,)``.

    Returns ``(distance (M,), point_on_segment (3, M), point_on_box (3, M))``, world frame.
    In the box frame ``f(s) = sum_i max(|x_i(s)| - h_i, 0)^2`` is convex and quadratic between
    the breakpoints ``x_i(s) = +-h_i``; each piece is minimised in closed form, and the best
    piece minimiser is exact (as in :func:`sara_app.geometry.shapes.segment_box_distance`).
    """
    R, c0 = T_world_box[:3, :3], T_world_box[:3, 3:4]
    a = R.T @ (p - c0)  # (3, M) box frame
    d = R.T @ (q - c0) - a
    h = half_extents_m[:, None]
    d_safe = np.where(np.abs(d) > 1e-12, d, 1e-12)
    M = a.shape[1]
    bp = np.empty((M, 8))
    bp[:, 0], bp[:, 7] = 0.0, 1.0
    bp[:, 1:4] = ((h - a) / d_safe).T
    bp[:, 4:7] = ((-h - a) / d_safe).T
    np.clip(bp, 0.0, 1.0, out=bp)
    bp.sort(axis=1)
    lo, hi = bp[:, :-1].T, bp[:, 1:].T  # (7, M) pieces
    mid = 0.5 * (lo + hi)
    qa = np.zeros_like(lo)
    qb = np.zeros_like(lo)
    for i in range(3):
        x = a[i] + mid * d[i]
        sign = (x > h[i]).astype(float) - (x < -h[i])
        act = sign * sign
        qa += act * d[i] * d[i]
        qb += act * (a[i] - sign * h[i]) * d[i]
    s = np.where(qa > 0.0, np.clip(-qb / np.where(qa > 0.0, qa, 1.0), lo, hi), lo)
    f = np.zeros_like(s)
    for i in range(3):
        ex = np.maximum(np.abs(a[i] + s * d[i]) - h[i], 0.0)
        f += ex * ex
    k = np.argmin(f, axis=0)
    cols = np.arange(M)
    s_best = s[k, cols]
    x = a + s_best * d
    cb = np.clip(x, -h, h)
    return np.sqrt(f[k, cols]), R @ x + c0, R @ cb + c0
