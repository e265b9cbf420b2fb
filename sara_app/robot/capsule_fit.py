"""Capsule fitting: the smallest-volume capsule found that encloses a link's collision primitives
(given as support points ``p_k`` with slacks ``rho_k``, :mod:`sara_app.robot.urdf`).

A capsule is convex and its distance function is convex, so if every ``p_k`` is within
``R - rho`` of the segment, the whole primitive is within ``R``. The radius is always recomputed
as ``max_k (dist(p_k, segment) + rho_k)``; the optimisation only moves the segment.

Fit: principal axes of the support points; for each candidate axis the two end insets are
chosen on a grid (the radius as a function of the insets separates into a function of each end,
so this is a pair of 1-D problems) to minimise the capsule volume; the best candidate is polished
by Nelder-Mead over both end points (radius recomputed for every trial). The fitted capsules are
cached per URDF file; per configuration only the end points are transformed.

The fit takes about 0.7 s for a 9-link arm, in every process that loads a robot; the end points
it finds are kept on disk (:func:`fit_cache_dir`), keyed by the SHA-256 of the link's support
points and slacks and of this file's source. The radius is never taken from the disk: it is
recomputed from the cached ends (:func:`enclosing_radius`), so a stale, foreign or corrupt
entry can cost volume but never containment. No cache folder (read-only home): fitted anew.
"""

from __future__ import annotations

import hashlib
import os
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from sara_app.errors import InputError
from sara_app.geometry.shapes import point_segment_distance
from sara_app.kernel_types import source_digest
from sara_app.robot.urdf import link_supports

__all__ = ["ENCLOSURE_SLACK_M", "enclosing_radius", "fit_capsule", "fitted_capsules"]

ENCLOSURE_SLACK_M = 1e-9
"""Added to every fitted radius to absorb floating-point rounding in the enclosure."""

_GRID = 129


def enclosing_radius(points: np.ndarray, rho: np.ndarray, ends: np.ndarray) -> float:
    """Smallest radius of the capsule on segment ``ends (2, 3)`` containing every
    ``ball(points[k], rho[k])``."""
    return float(np.max(point_segment_distance(points, ends) + rho))


def _volume(length: np.ndarray | float, radius: np.ndarray | float) -> np.ndarray | float:
    return np.pi * radius**2 * length + 4.0 / 3.0 * np.pi * radius**3


def _best_insets(
    t: np.ndarray, perp2: np.ndarray, rho: np.ndarray, lo: float, hi: float
) -> tuple[float, float, float]:
    """Grid search of the segment ``[a, b]`` on a fixed line: ``(volume, a, b)``.

    ``R(a, b) = max(G(a), H(b))`` with ``G(a) = max_k sqrt(perp_k^2 + max(a - t_k, 0)^2) + rho_k``
    and ``H`` the mirror image: points below ``a`` are the only ones ``a`` affects.
    """
    best = (np.inf, lo, hi)
    for _ in range(3):  # refine around the best cell
        a = np.linspace(lo, hi, _GRID)
        G = np.max(np.sqrt(perp2 + np.maximum(a[:, None] - t, 0.0) ** 2) + rho, axis=1)
        H = np.max(np.sqrt(perp2 + np.maximum(t - a[:, None], 0.0) ** 2) + rho, axis=1)
        R = np.maximum(G[:, None], H[None, :])
        length = a[None, :] - a[:, None]
        V = np.where(length >= 0, _volume(np.maximum(length, 0.0), R), np.inf)
        i, j = np.unravel_index(int(np.argmin(V)), V.shape)
        if V[i, j] < best[0]:
            best = (float(V[i, j]), float(a[i]), float(a[j]))
        step = (hi - lo) / (_GRID - 1)
        lo, hi = max(lo, min(a[i], a[j]) - step), min(hi, max(a[i], a[j]) + step)
        if hi - lo < 1e-7:
            break
    return best


def fit_capsule(
    points: np.ndarray, rho: np.ndarray | float = 0.0, axis_points: np.ndarray | None = None
) -> tuple[np.ndarray, float]:
    """A small capsule ``(ends (2, 3), radius)`` containing every ``ball(points[k], rho[k])``.

    ``axis_points`` (default: ``points``) only steer the choice of the principal axes. The
    returned radius is the exact enclosing radius for the returned ends plus
    :data:`ENCLOSURE_SLACK_M`, so containment does not depend on the optimisation's quality.
    """
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    rho_arr = np.broadcast_to(np.asarray(rho, dtype=float), P.shape[:1]).copy()
    if P.shape[0] == 0 or not np.all(np.isfinite(P)) or np.any(rho_arr < 0):
        raise InputError(f"fit_capsule: {P.shape[0]} points / rho invalid; expected finite data")
    guide = P if axis_points is None else np.asarray(axis_points, dtype=float).reshape(-1, 3)
    centre = guide.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((guide - centre).T) if len(guide) > 1 else np.eye(3))
    best_vol, best_ends = np.inf, np.stack([centre, centre])
    d = P - centre
    for axis in vecs.T[::-1]:  # principal axis first
        t = d @ axis
        perp2 = np.maximum(np.einsum("ki,ki->k", d, d) - t * t, 0.0)
        vol, a, b = _best_insets(t, perp2, rho_arr, float(t.min()), float(t.max()))
        if vol < best_vol:
            best_vol, best_ends = vol, np.stack([centre + a * axis, centre + b * axis])

    def objective(x: np.ndarray) -> float:
        p0, seg = x[:3], x[3:] - x[:3]
        rel = P - p0
        ss = float(seg @ seg)
        s = np.clip(rel @ seg / ss, 0.0, 1.0) if ss > 1e-24 else np.zeros(len(P))
        gap = rel - s[:, None] * seg
        r = float(np.max(np.sqrt(np.einsum("ki,ki->k", gap, gap)) + rho_arr))
        return float(_volume(np.sqrt(ss), r))

    # Nelder-Mead polish over both end points, restarted once with a smaller simplex.
    # (scipy.optimize here, not at the top: only a fit that missed the cache needs it, and every
    # cell process imports this module: 0.25 s of start-up each)
    from scipy.optimize import minimize

    x = best_ends.ravel()
    f = objective(x)
    size = max(float(np.ptp(P, axis=0).max()), 1e-3)
    for step in (0.05 * size, 0.01 * size):
        res = minimize(
            objective,
            x,
            method="Nelder-Mead",
            options={
                "initial_simplex": np.vstack([x, x + step * np.eye(6)]),
                "xatol": 1e-6,
                "fatol": 1e-11,
                "maxiter": 3000,
            },
        )
        if res.fun < f:
            x, f = res.x, float(res.fun)
    ends = x.reshape(2, 3)
    return ends, enclosing_radius(P, rho_arr, ends) + ENCLOSURE_SLACK_M


_FIT_CACHE: dict[tuple[str, int, int], tuple[tuple[str, ...], np.ndarray, np.ndarray]] = {}
_SOURCE_SHA256 = source_digest(sys.modules[__name__])


def fit_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/sara_app/capsules``, else ``~/.cache/sara_app/capsules``."""
    xdg = os.environ.get("XDG_CACHE_HOME")
    root = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return root / "sara_app" / "capsules"


def _cached_fit(
    points: np.ndarray, rho: np.ndarray, axis_points: np.ndarray
) -> tuple[np.ndarray, float]:
    """:func:`fit_capsule` of one link, its end points kept on disk (module notes)."""
    P = np.ascontiguousarray(points, dtype=float).reshape(-1, 3)
    rho_arr = np.ascontiguousarray(np.broadcast_to(np.asarray(rho, dtype=float), P.shape[:1]))
    guide = np.ascontiguousarray(axis_points, dtype=float)
    digest = hashlib.sha256(_SOURCE_SHA256.encode())
    for a in (P, rho_arr, guide):
        digest.update(str(a.shape).encode() + a.tobytes())
    path = fit_cache_dir() / f"{digest.hexdigest()}.npy"
    try:
        ends = np.load(path, allow_pickle=False)
        if ends.shape == (2, 3) and ends.dtype == np.float64 and np.all(np.isfinite(ends)):
            return ends, enclosing_radius(P, rho_arr, ends) + ENCLOSURE_SLACK_M
    except (OSError, ValueError, EOFError):
        pass  # absent or unreadable: fitted anew below
    ends, radius = fit_capsule(P, rho_arr, guide)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".{os.getpid()}.tmp")
        with open(tmp, "wb") as f:
            np.save(f, ends, allow_pickle=False)
        os.replace(tmp, path)  # atomic: a reader sees the whole entry or none
    except OSError:
        pass  # no cache folder: the next process fits again
    return ends, radius


def fitted_capsules(path: Path, root: ET.Element) -> tuple[tuple[str, ...], np.ndarray, np.ndarray]:
    stat = path.stat()
    key = (str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    if key not in _FIT_CACHE:
        supports = link_supports(root, path.parent)
        names = tuple(supports)
        ends = np.zeros((len(names), 2, 3))
        radii = np.zeros(len(names))
        for i, name in enumerate(names):
            ends[i], radii[i] = _cached_fit(*supports[name])
        _FIT_CACHE[key] = (names, ends, radii)
    names, ends, radii = _FIT_CACHE[key]
    return names, ends.copy(), radii.copy()
