"""A :class:`PathTrajectory` is a polyline through joint-space waypoints ``(W, n)`` whose
corners are replaced by blends, parameterised by a path coordinate ``s`` in ``[0, S]`` (rad, the
Euclidean joint-space arc length on the straight parts). On a straight piece
``q(s) = p + (s - s_k) u`` with a unit direction ``u``. A corner at waypoint ``w`` between unit
directions ``u_in`` and ``u_out`` is replaced, from ``w - d u_in`` to ``w + d u_out`` (length
``L = 2 d`` in ``s``), by the curve whose tangent turns from ``u_in`` to ``u_out`` with a cubic
smoothstep ``h(x) = 3 x^2 - 2 x^3``, ``x = (s - s_k) / L``::

    dq/ds   = u_in + h(x) (u_out - u_in)
    d2q/ds2 = h'(x) (u_out - u_in) / L          h'  = 6 x (1 - x),  |h'|  <= 3/2
    d3q/ds3 = h''(x) (u_out - u_in) / L^2       h'' = 6 - 12 x,     |h''| <= 6

``d2q/ds2`` is zero at both ends of a blend, so the path is C2 in ``s`` with a bounded
(piecewise continuous) third derivative: a jerk-limited time-scaling never has to stop at a
corner. Every tangent is a convex combination of ``u_in`` and ``u_out``, so
``|dq_j/ds| <= max(|u_in_j|, |u_out_j|)`` (blends never ask more joint speed per unit path speed
than the straight parts next to them) and ``dq_j/ds`` is monotone along a blend. The blend lies in
the triangle ``(w - d u_in, w, w + d u_out)`` (its barycentric weights are
``(1 - x)^3 (1 + x)``, ``2 x - 4 H(x)``, ``2 H(x)`` with ``H(x) = x^3 - x^4 / 2``, all >= 0), so
the whole path lies in the convex hull of its waypoints: waypoints inside the joint position box
put the whole path inside it. The blend misses the corner by ``3 d |u_out - u_in| / 16``
(at most ``3 d / 8``). ``d`` is ``blend_distance`` (default 0.1 rad), shortened to half of each
neighbouring segment (the first and last segments keep at least half their length straight).

Time-scaling. Along the path ``v = q' s'``, ``a = q'' s'^2 + q' s''``,
``j = q''' s'^3 + 3 q'' s' s'' + q' s'''`` (primes: derivatives in ``s``; ``s'``, ``s''``,
``s'''``: path speed, acceleration, jerk). For every piece ``k`` the per-joint maxima
``M1 = max|q'|``, ``M2 = max|q''|``, ``M3 = max|q'''|`` over the piece give a box
``(V_k, A_k, J_k)`` such that ``0 <= s' <= V_k``, ``|s''| <= A_k``, ``|s'''| <= J_k`` on the
piece keeps every joint within its velocity, acceleration and jerk limits::

    A_k = min_j (a_j - M2_j V_k^2) / M1_j
    J_k = min_j (j_j - M3_j V_k^3 - 3 M2_j V_k A_k) / M1_j

On straight pieces (``M2 = M3 = 0``) this is exact: ``V_k = min_j v_j / |u_j|`` and the
full acceleration and jerk budgets. On blends, ``V_k`` (the admissible path speed) is the largest
speed that leaves at least ``tangential_share`` (default 0.5) of every joint's acceleration and
jerk budget to ``s''`` and ``s'''``. The boxes are computed once per path
(:mod:`sara_app.robot.path_limits`).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass

import numpy as np

from sara_app.errors import RobotModelError
from sara_app.geometry.shapes import point_segment_distance
from sara_app.robot.joints import (
    S_TOL,
    check_waypoints,
)
from sara_app.robot.model import JointLimits

__all__ = ["PathTrajectory", "waypoints_ahead"]


def _h(x: np.ndarray) -> np.ndarray:
    return x * x * (3.0 - 2.0 * x)


def _dh(x: np.ndarray) -> np.ndarray:
    return 6.0 * x * (1.0 - x)


def _ddh(x: np.ndarray) -> np.ndarray:
    return 6.0 - 12.0 * x


@dataclass
class _Pieces:
    """Piece table: ``q(s) = org + L (x u + H(x) dl)``, ``x = x0 + (s - s0) / L`` in [x0, x1]."""

    s0: np.ndarray  # (P,) start of each piece in s
    length: np.ndarray  # (P,) length in s
    org: np.ndarray  # (P, n)
    L: np.ndarray  # (P,)
    x0: np.ndarray  # (P,)
    u: np.ndarray  # (P, n)
    dl: np.ndarray  # (P, n) u_out - u_in (zero on straight pieces)
    blend: np.ndarray  # (P,) bool

    @staticmethod
    def concat(parts: list[_Pieces]) -> _Pieces:
        names = ("s0", "length", "org", "L", "x0", "u", "dl", "blend")
        return _Pieces(*(np.concatenate([getattr(p, k) for p in parts]) for k in names))


def _polyline_pieces(
    points: np.ndarray, blend_distance: float, s_start: float, first_full: bool
) -> _Pieces:
    """Pieces of a blended polyline (consecutive duplicates removed by the caller)."""
    n = points.shape[1]
    seg = np.diff(points, axis=0)
    ln = np.linalg.norm(seg, axis=1)
    u = seg / ln[:, None]
    m = len(ln)
    # blend half-length per interior corner i (between segment i-1 and i), i = 1..m-1
    share = np.full(m, 0.5)
    if first_full and m > 1:
        share[0] = 1.0
    d = np.zeros(m + 1)
    for i in range(1, m):
        d[i] = min(blend_distance, share[i - 1] * ln[i - 1], 0.5 * ln[i])
    rows: list[tuple[float, np.ndarray, float, float, np.ndarray, np.ndarray, bool]] = []
    zero = np.zeros(n)
    for i in range(m):
        lin = ln[i] - d[i] - d[i + 1]
        if lin > S_TOL * 1e-3:
            rows.append((lin, points[i] + d[i] * u[i], lin, 0.0, u[i], zero, False))
        if i + 1 < m and d[i + 1] > 0.0:
            dd = d[i + 1]
            org = points[i + 1] - dd * u[i]
            rows.append((2.0 * dd, org, 2.0 * dd, 0.0, u[i], u[i + 1] - u[i], True))
    lengths = np.array([r[0] for r in rows])
    s0 = s_start + np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    return _Pieces(
        s0=s0,
        length=lengths,
        org=np.array([r[1] for r in rows]).reshape(-1, n),
        L=np.array([r[2] for r in rows]),
        x0=np.array([r[3] for r in rows]),
        u=np.array([r[4] for r in rows]).reshape(-1, n),
        dl=np.array([r[5] for r in rows]).reshape(-1, n),
        blend=np.array([r[6] for r in rows], dtype=bool),
    )


def waypoints_ahead(waypoints: np.ndarray, q: np.ndarray) -> np.ndarray:
    """The waypoints ``(W, n)`` still ahead of a robot at ``q (n,)`` that stands on (or near)
    the polyline through them: those after the segment nearest to ``q`` (the later segment
    where two are as near: a corner), ``(W', n)`` with ``W' >= 1``; all of them for a single
    waypoint. A plan from ``q`` through them keeps to the task's path (within its blends)
    instead of going straight to its end through whatever the corners went around."""
    w = np.asarray(waypoints, dtype=float)
    if len(w) < 2:
        return w
    dist = point_segment_distance(np.asarray(q, dtype=float), np.stack([w[:-1], w[1:]], axis=1))
    nearest = int(np.flatnonzero(dist <= dist.min() + 1e-12)[-1])  # the later one of a tie
    return w[nearest + 1 :]


def _dedupe(points: np.ndarray) -> np.ndarray:
    keep = [0]
    for i in range(1, len(points)):
        if np.linalg.norm(points[i] - points[keep[-1]]) > S_TOL:
            keep.append(i)
    return points[keep]


class PathTrajectory:
    """Blended polyline through joint-space waypoints ``(W, n)``, parameterised by ``s``.

    ``q(s)``, ``dq(s)``, ``d2q(s)``, ``d3q(s)`` accept a scalar or an array of path coordinates
    (clamped to ``[0, S]``) and return ``(n,)`` or ``(K, n)``. With ``limits`` the waypoints are
    checked against the joint position box (the path stays in their convex hull, see the module
    notes). ``blend_distance`` (rad, > 0) is the corner blend half-length ``d``.
    """

    def __init__(
        self,
        waypoints: object,
        *,
        blend_distance: float = 0.1,
        limits: JointLimits | None = None,
    ) -> None:
        if not (isinstance(blend_distance, int | float) and math.isfinite(blend_distance)):
            raise RobotModelError(f"blend_distance = {blend_distance!r}; expected a number > 0")
        if blend_distance <= 0:
            raise RobotModelError(
                f"blend_distance = {blend_distance!r} rad; expected > 0 (corners must be blended)"
            )
        wps = check_waypoints(waypoints, limits)
        self.waypoints = wps
        self.blend_distance = float(blend_distance)
        pts = _dedupe(wps)
        if len(pts) >= 2:
            pieces = _polyline_pieces(pts, self.blend_distance, 0.0, first_full=False)
        else:
            pieces = None
        self._setup(pts[0], pieces)

    @classmethod
    def _from_pieces(
        cls, waypoints: np.ndarray, blend_distance: float, start: np.ndarray, pieces: _Pieces
    ) -> PathTrajectory:
        self = cls.__new__(cls)
        self.waypoints = waypoints
        self.blend_distance = blend_distance
        self._setup(start, pieces)
        return self

    def _setup(self, start: np.ndarray, pieces: _Pieces | None) -> None:
        self.n_joints = int(start.shape[0])
        self._start = np.array(start, dtype=float)
        self._p = pieces
        if pieces is None:
            self.length = 0.0
            self._s0_list: list[float] = [0.0]
            # for the shielded trajectory's kernel: one piece of length 0 at the point (q there,
            # every derivative and maximum 0)
            n = self.n_joints
            poly = np.zeros((1, 5, 4 * n))
            poly[0, 0, :n] = self._start
            z = np.zeros((1, n))
            self._piece_tables = (np.zeros(1), np.zeros(1), poly, z, z, z)
            return
        p = pieces
        self.length = float(p.s0[-1] + p.length[-1])
        self._s0_list = [float(x) for x in p.s0]
        self._invL = 1.0 / p.L
        self._x1 = p.x0 + p.length * self._invL
        self._x0_list = p.x0.tolist()
        self._x1_list = self._x1.tolist()
        self._L_list = p.L.tolist()
        self._invL_list = self._invL.tolist()
        # per-piece maxima of |q'|, |q''|, |q'''| over the piece's x range
        x0, x1 = p.x0, self._x1
        qs0 = p.u + _h(x0)[:, None] * p.dl
        qs1 = p.u + _h(x1)[:, None] * p.dl
        self.M1 = np.maximum(np.abs(qs0), np.abs(qs1))
        dh_max = _dh(np.clip(0.5, x0, x1))
        ddh_max = np.maximum(np.abs(_ddh(x0)), np.abs(_ddh(x1)))
        adl = np.abs(p.dl)
        self.M2 = adl * (dh_max * self._invL)[:, None]
        self.M3 = adl * (ddh_max * self._invL**2)[:, None]
        with np.errstate(divide="ignore"):
            self.invM1 = np.where(self.M1 > 0.0, 1.0 / np.where(self.M1 > 0, self.M1, 1.0), np.inf)
        self._qs_start = qs0  # dq/ds at each piece start (continuous across pieces)
        # q as a quartic in tau = s - s_k (H(x0 + y) expanded, y = tau / L)
        L = p.L[:, None]
        x0c = x0[:, None]
        c0 = p.org + L * (x0c * p.u + (x0c**3 - 0.5 * x0c**4) * p.dl)
        c1 = p.u + (3 * x0c**2 - 2 * x0c**3) * p.dl
        c2 = (3 * x0c - 3 * x0c**2) / L * p.dl
        c3 = (1 - 2 * x0c) / L**2 * p.dl
        c4 = -0.5 / L**3 * p.dl
        # coefficient blocks per power of tau (rows) for [q | dq | d2q | d3q] (columns)
        z = np.zeros_like(c0)
        self._poly = np.stack(
            [
                np.hstack([c0, c1, 2 * c2, 6 * c3]),
                np.hstack([c1, 2 * c2, 6 * c3, 24 * c4]),
                np.hstack([c2, 3 * c3, 12 * c4, z]),
                np.hstack([c3, 4 * c4, z, z]),
                np.hstack([c4, z, z, z]),
            ],
            axis=1,
        )  # (P, 5, 4 n)
        self._piece_tables = (p.s0, p.length, self._poly, self.M1, self.M2, qs0)

    # -- geometry ----------------------------------------------------------------------------

    @property
    def n_pieces(self) -> int:
        return 0 if self._p is None else len(self._s0_list)

    @property
    def piece_starts(self) -> np.ndarray:
        """Start of every piece in ``s`` (``(P,)``)."""
        return np.array(self._s0_list)

    @property
    def piece_is_blend(self) -> np.ndarray:
        return np.zeros(0, bool) if self._p is None else self._p.blend.copy()

    @property
    def piece_tables(self) -> tuple[np.ndarray, ...]:
        """Per-piece tables for compiled kernels: starts, lengths ``(P,)``, quartic coefficients
        ``(P, 5, 4 n)`` of ``[q | dq/ds | d2q/ds2 | d3q/ds3]`` in ``tau = s - s_k``, maxima of
        ``|dq/ds|``, ``|d2q/ds2|`` ``(P, n)`` and ``dq/ds`` at every piece start ``(P, n)``."""
        if self._p is None:
            raise RobotModelError("a path of one point has no pieces")
        return self._piece_tables

    def piece_index(self, s: float) -> int:
        """Index of the piece containing ``s`` (scalar)."""
        return max(bisect.bisect_right(self._s0_list, s) - 1, 0)

    def derivatives(self, s: object, order: int = 2) -> list[np.ndarray]:
        """``[q, dq/ds, ..., d^order q/ds^order]`` at ``s`` (``order`` <= 3)."""
        if isinstance(s, float | int) and self._p is not None and math.isfinite(s):
            return self._derivatives_at(float(s), order)
        s_arr = np.asarray(s, dtype=float)
        scalar = s_arr.ndim == 0
        s_arr = np.atleast_1d(s_arr)
        if not np.all(np.isfinite(s_arr)):
            raise RobotModelError(f"path coordinate s = {s!r}; expected finite values")
        out = self._derivatives_array(s_arr, order)
        return [o[0] for o in out] if scalar else out

    def _derivatives_array(self, s_arr: np.ndarray, order: int) -> list[np.ndarray]:
        """:meth:`derivatives` for a finite float array (no checks)."""
        shape = (*s_arr.shape, self.n_joints)
        p = self._p
        if p is None:
            out = [np.broadcast_to(self._start, shape).copy()]
            out += [np.zeros(shape) for _ in range(order)]
        else:
            # every piece is a quartic in tau = s - s_k: one product with the monomials
            flat = s_arr.reshape(-1)
            k = np.searchsorted(p.s0, flat, side="right") - 1
            np.maximum(k, 0, out=k)
            np.minimum(k, len(p.s0) - 1, out=k)
            tau = flat - p.s0[k]
            np.maximum(tau, 0.0, out=tau)
            np.minimum(tau, p.length[k], out=tau)
            n = self.n_joints
            m = (order + 1) * n
            mono = np.vander(tau, 5, increasing=True)[:, None, :]
            vals = np.matmul(mono, self._poly[k, :, :m])[:, 0, :]
            out = [vals[:, i * n : (i + 1) * n].reshape(shape) for i in range(order + 1)]
        return out

    def _derivatives_at(self, s: float, order: int) -> list[np.ndarray]:
        """Scalar fast path of :meth:`derivatives`."""
        p = self._p
        if p is None:  # the caller checked; an empty path has no pieces
            raise RobotModelError("path without pieces has no derivatives at a point")
        k = self.piece_index(s)
        x0 = self._x0_list[k]
        x = min(max(x0 + (s - self._s0_list[k]) * self._invL_list[k], x0), self._x1_list[k])
        L = self._L_list[k]
        u, dl = p.u[k], p.dl[k]
        x2 = x * x
        out = [p.org[k] + L * (x * u + (x2 * x - 0.5 * x2 * x2) * dl)]
        if order >= 1:
            out.append(u + (x2 * (3.0 - 2.0 * x)) * dl)
        if order >= 2:
            out.append((6.0 * x * (1.0 - x) / L) * dl)
        if order >= 3:
            out.append(((6.0 - 12.0 * x) / (L * L)) * dl)
        return out

    def q(self, s: object) -> np.ndarray:
        return self.derivatives(s, 0)[0]

    def dq(self, s: object) -> np.ndarray:
        return self.derivatives(s, 1)[1]

    def d2q(self, s: object) -> np.ndarray:
        return self.derivatives(s, 2)[2]

    def d3q(self, s: object) -> np.ndarray:
        return self.derivatives(s, 3)[3]

    def interval_bounds(
        self, s: np.ndarray, dq: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For every ``[s_k, s_k+1]`` of non-decreasing path samples ``s`` ``(K+1,)`` with
        ``dq = dq/ds(s)``: ``(D1, M1, M2)``, each ``(K, n)``.

        ``D1`` is the exact ``max |dq_j/ds|`` over the interval (``dq_j/ds`` is monotone on
        every piece: the extremes are at the ends and at piece starts inside); ``M1``, ``M2``
        are the piece maxima of ``|dq_j/ds|``, ``|d2q_j/ds2|`` over the pieces it touches.
        """
        ad = np.abs(dq)
        D1 = np.maximum(ad[:-1], ad[1:])
        if self._p is None:
            z = np.zeros_like(D1)
            return D1, z, z
        P = self.n_pieces
        k = np.searchsorted(self._p.s0, s, side="right") - 1
        np.maximum(k, 0, out=k)
        np.minimum(k, P - 1, out=k)
        k0, k1 = k[:-1], k[1:]
        M1 = np.maximum(self.M1[k0], self.M1[k1])
        M2 = np.maximum(self.M2[k0], self.M2[k1])
        for i in np.flatnonzero(k1 != k0).tolist():
            a, b = int(k0[i]), int(k1[i])
            inner = self._qs_start[a + 1 : b + 1]
            D1[i] = np.maximum(D1[i], np.abs(inner).max(axis=0))
            if b - a > 1:
                M1[i] = self.M1[a : b + 1].max(axis=0)
                M2[i] = self.M2[a : b + 1].max(axis=0)
        return D1, M1, M2

    # -- composition (replanning) -------------------------------------------------------------

    def continued(
        self,
        s_now: float,
        s_b: float,
        points: np.ndarray,
        waypoints: np.ndarray,
        blend_distance: float,
    ) -> PathTrajectory:
        """This path over ``[s_now, s_b]`` (re-based: ``s_now`` becomes 0), then a blended
        polyline from ``q(s_b)`` through ``points (m, n)`` (``m`` may be 0) whose first segment
        stays straight. ``waypoints``: the request the new path serves (its ``waypoints``)."""
        prefix = self._clipped(s_now, s_b)
        q_now = self.q(s_now)
        wps = np.vstack([q_now[None, :], waypoints])
        if len(points) == 0:
            if prefix is None:
                raise RobotModelError("nothing to continue: an empty stretch and no new points")
            return PathTrajectory._from_pieces(wps, blend_distance, q_now, prefix)
        pts = _dedupe(np.vstack([self.q(s_b)[None, :], points]))
        tail = _polyline_pieces(pts, blend_distance, s_b - s_now, first_full=True)
        pieces = tail if prefix is None else _Pieces.concat([prefix, tail])
        return PathTrajectory._from_pieces(wps, blend_distance, q_now, pieces)

    def _clipped(self, s_a: float, s_b: float) -> _Pieces | None:
        """The pieces over ``[s_a, s_b]``, re-based so ``s_a`` becomes 0."""
        p = self._p
        if p is None or s_b - s_a <= S_TOL * 1e-3:
            return None
        k0, k1 = self.piece_index(s_a), self.piece_index(s_b)
        if k1 > k0 and s_b - self._s0_list[k1] <= S_TOL * 1e-3:
            k1 -= 1
        ks = np.arange(k0, k1 + 1)
        starts = np.maximum(p.s0[ks], s_a)
        ends = np.minimum(p.s0[ks] + p.length[ks], s_b)
        keep = ends - starts > 0.0
        ks, starts, ends = ks[keep], starts[keep], ends[keep]
        x0 = p.x0[ks] + (starts - p.s0[ks]) * self._invL[ks]
        return _Pieces(
            s0=starts - s_a,
            length=ends - starts,
            org=p.org[ks],
            L=p.L[ks],
            x0=x0,
            u=p.u[ks],
            dl=p.dl[ks],
            blend=p.blend[ks],
        )
