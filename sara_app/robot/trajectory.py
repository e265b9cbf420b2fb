"""Long-term task trajectory in joint space: blended polyline paths and an online path follower.

Path. A :class:`PathTrajectory` is a polyline through joint-space waypoints ``(W, n)`` whose
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
jerk budget to ``s''`` and ``s'''``. The boxes are computed once per path.

Follower. :class:`PathFollower` plans the scalar path motion online with piecewise-constant
path jerk. Every step it aims for the admissible speed of the current piece with the time-optimal
jerk-limited velocity profile (limits: the smallest box over a look-ahead window that covers any
stopping distance), and starts braking, at the exact instant inside the step, when a time-optimal
brake from the end of the step would no longer reach the lower admissible speed of an upcoming
piece before that piece, or standstill at the end of the path. A step is committed only when the
joint limits provably hold over it and a path-consistent failsafe stop
(:func:`sara_app.robot.failsafe.plan_stop`) exists from its end; otherwise the follower executes
the failsafe it already holds (recursive feasibility: the tail of a valid stop is a valid stop).
A ``speed_cap`` (path speed, default inf; set by the PFL shield for speed scaling) lowers every
admissible speed the follower aims for to at most the cap: the same planning, slower targets.

Fallback steps (counted in ``fallback_steps``) do not happen on a path followed from rest to
rest; after a replan they can (for instance when the new goal forces the robot to stop where the
failsafe it holds stops): the robot then brakes along that failsafe, which is always valid.

Replanning (:meth:`PathFollower.replan`) never forces a stop of a moving robot. The new path
keeps the current path's geometry up to the end of the failsafe held (pushed on to the end of a
blend if it ends inside one), so that failsafe remains valid on the new path; from there it runs
straight on in the current direction (at most ``blend_distance``, at most half way to the first
new waypoint, inside the joint position box) to a new corner, blended like any other, and on
through the new waypoints. If the follower could not slow down to the new corner's admissible
speed before it, the corner is moved further along the straight line. Position, velocity and
acceleration are continuous because the geometry around the robot does not change. Special
cases: at rest the new path starts at the current position; a request equal to the previous one
(or a single goal equal to the current end) changes nothing; if the robot is already braking to
a standstill within ``blend_distance`` of the current end, or a joint limit leaves no room to go
on straight, the current path is finished first and the new one starts from rest.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sara_app.errors import RobotModelError
from sara_app.robot.model import JointLimits

if TYPE_CHECKING:
    from sara_app.robot.failsafe import StopProfile

__all__ = [
    "FollowerStep",
    "JointLimits",
    "JointState",
    "PathFollower",
    "PathTrajectory",
    "ScalarProfile",
    "time_scaling",
    "velocity_phases",
]

LIMIT_MARGIN = 1e-9
"""Relative margin taken off every path-speed box so rounding can never cross a joint limit."""

_S_TOL = 1e-9  # rad: path positions closer than this are the same point
_REST_V = 1e-9  # path speed below which (with _REST_A) the robot counts as standing still
_REST_A = 1e-7


# ----------------------------------------------------------------------------------------------
# States and limits


@dataclass(frozen=True)
class JointState:
    """Joint position (rad), velocity (rad/s) and acceleration (rad/s^2), arrays ``(n,)``."""

    q: np.ndarray
    v: np.ndarray
    a: np.ndarray


class _LimitArrays:
    """Float copies of a :class:`JointLimits` checked against a joint count."""

    __slots__ = ("source", "q_min", "q_max", "v", "a", "j")

    def __init__(self, limits: JointLimits, n: int) -> None:
        self.source = limits
        arrays = []
        for name in ("q_min", "q_max", "v_max", "a_max", "j_max"):
            arr = np.asarray(getattr(limits, name), dtype=float)
            if arr.shape != (n,):
                raise RobotModelError(
                    f"joint limit {name} has shape {arr.shape}; expected ({n},) for {n} joints"
                )
            if not np.all(np.isfinite(arr)):
                raise RobotModelError(f"joint limit {name} = {arr.tolist()} is not finite")
            arrays.append(arr)
        self.q_min, self.q_max, self.v, self.a, self.j = arrays
        for name, arr in (("v_max", self.v), ("a_max", self.a), ("j_max", self.j)):
            if np.any(arr <= 0):
                i = int(np.flatnonzero(arr <= 0)[0])
                raise RobotModelError(f"joint {i}: {name} = {arr[i]}; expected a positive value")


def limit_arrays(limits: JointLimits, n: int) -> _LimitArrays:
    """Checked float arrays of ``limits`` for ``n`` joints."""
    if not isinstance(limits, JointLimits):
        raise RobotModelError(
            f"limits is a {type(limits).__name__}; expected sara_app.robot.model.JointLimits"
        )
    return _LimitArrays(limits, n)


def check_waypoints(waypoints: object, limits: JointLimits | None = None, n: int | None = None):
    """Waypoints as a float array ``(W, n)``; raise :class:`RobotModelError` naming the problem.

    Checks the shape, finiteness and, with ``limits``, the joint position box; errors name the
    waypoint index and the joint index.
    """
    if limits is not None and not isinstance(limits, JointLimits):
        raise RobotModelError(
            f"limits is a {type(limits).__name__}; expected sara_app.robot.model.JointLimits"
        )
    try:
        wps = np.array(waypoints, dtype=float)
    except (TypeError, ValueError) as exc:
        raise RobotModelError(f"waypoints cannot be read as a float array: {exc}") from None
    if n is None and limits is not None:
        n = int(np.shape(limits.q_min)[0])
    if wps.ndim != 2 or wps.shape[0] < 1 or wps.shape[1] < 1:
        want = f"(W, {n})" if n is not None else "(W, n)"
        raise RobotModelError(f"waypoints have shape {wps.shape}; expected {want} with W >= 1")
    if n is not None and wps.shape[1] != n:
        raise RobotModelError(
            f"waypoints have {wps.shape[1]} joints (shape {wps.shape}); expected {n}"
        )
    bad = ~np.isfinite(wps)
    if bad.any():
        i, j = (int(x) for x in np.argwhere(bad)[0])
        raise RobotModelError(
            f"waypoint {i} joint {j} is {wps[i, j]}; expected a finite joint position"
        )
    if limits is not None:
        lo = np.asarray(limits.q_min, dtype=float)
        hi = np.asarray(limits.q_max, dtype=float)
        out = (wps < lo) | (wps > hi)
        if out.any():
            i, j = (int(x) for x in np.argwhere(out)[0])
            raise RobotModelError(
                f"waypoint {i} joint {j} = {wps[i, j]:.6g} rad is outside the joint range "
                f"[{lo[j]:.6g}, {hi[j]:.6g}] rad: goal unreachable"
            )
    return wps


# ----------------------------------------------------------------------------------------------
# Scalar jerk-limited profiles (path coordinate s as a function of time)


def velocity_phases(
    v0: float, a0: float, vt: float, A: float, J: float
) -> tuple[list[float], list[float]]:
    """Time-optimal phases ``(durations, jerks)`` from ``(v0, a0)`` to velocity ``vt`` at rest
    acceleration (``a = 0``) with ``|a| <= A`` (an initial ``|a0| > A`` is first ramped back)
    and ``|jerk| <= J``: at most three phases (jerk +-J, 0, -+J)."""
    two_j = 2.0 * J
    vr = v0 + a0 * abs(a0) / two_j  # velocity reached by ramping a to zero at once
    dv = vt - vr
    if abs(dv) <= 1e-12 * (abs(v0) + abs(vt) + a0 * a0 / two_j) + 1e-15:
        if a0 == 0.0:
            return [], []
        return [abs(a0) / J], [-J if a0 > 0.0 else J]
    d = 1.0 if dv > 0.0 else -1.0
    ap = d * a0
    dv_total = d * (vt - v0)
    if ap > A:
        hold = (dv_total - ap * ap / two_j) / A
        durs = [(ap - A) / J, max(hold, 0.0), A / J]
        jerks = [-J, 0.0, -J]
    else:
        p = math.sqrt(max(J * dv_total + 0.5 * ap * ap, 0.0))
        if p <= A:
            durs = [(p - ap) / J, p / J]
            jerks = [J, -J]
        else:
            hold = (dv_total - (2.0 * A * A - ap * ap) / two_j) / A
            durs = [(A - ap) / J, max(hold, 0.0), A / J]
            jerks = [J, 0.0, -J]
    out_d: list[float] = []
    out_j: list[float] = []
    for t, j in zip(durs, jerks, strict=True):
        if t > 0.0:
            out_d.append(t)
            out_j.append(d * j)
    return out_d, out_j


def phases_end(
    s: float, v: float, a: float, durs: list[float], jerks: list[float]
) -> tuple[float, float, float]:
    """State ``(s, v, a)`` at the end of the phases."""
    for t, j in zip(durs, jerks, strict=True):
        s += t * (v + t * (0.5 * a + t * j / 6.0))
        v += t * (a + 0.5 * t * j)
        a += t * j
    return s, v, a


def phases_at(
    s: float, v: float, a: float, durs: list[float], jerks: list[float], t: float
) -> tuple[float, float, float]:
    """State at time ``t`` (after the last phase the motion goes on with zero jerk)."""
    for T, j in zip(durs, jerks, strict=True):
        if t <= T:
            return (
                s + t * (v + t * (0.5 * a + t * j / 6.0)),
                v + t * (a + 0.5 * t * j),
                a + t * j,
            )
        s += T * (v + T * (0.5 * a + T * j / 6.0))
        v += T * (a + 0.5 * T * j)
        a += T * j
        t -= T
    return s + t * (v + 0.5 * t * a), v + t * a, a


def phase_maxima(
    v: float, a: float, durs: list[float], jerks: list[float]
) -> tuple[float, float, float]:
    """Exact ``max s'``, ``max |s''|``, ``max |jerk|`` over the phases from ``(v, a)``."""
    vmax, amax, jmax = v, abs(a), 0.0
    for T, j in zip(durs, jerks, strict=True):
        if j != 0.0:
            tau = -a / j
            if 0.0 < tau < T:
                vmax = max(vmax, v + tau * (a + 0.5 * tau * j))
            jmax = max(jmax, abs(j))
        v += T * (a + 0.5 * T * j)
        a += T * j
        vmax = max(vmax, v)
        amax = max(amax, abs(a))
    return vmax, amax, jmax


def _cut(durs: list[float], jerks: list[float], t: float) -> tuple[list[float], list[float]]:
    """The phases over ``[0, t]``, padded with a zero-jerk phase if they end earlier."""
    out_d: list[float] = []
    out_j: list[float] = []
    rest = t
    for T, j in zip(durs, jerks, strict=True):
        if rest <= 0.0:
            break
        take = T if T < rest else rest
        out_d.append(take)
        out_j.append(j)
        rest -= take
    if rest > 0.0:
        out_d.append(rest)
        out_j.append(0.0)
    return out_d, out_j


class ScalarProfile:
    """Piecewise-constant-jerk motion of a scalar ``s(t)``, ``t >= 0``, from ``(s0, v0, a0)``.

    Phase ``i`` runs over ``[tb[i], tb[i+1]]`` with jerk ``jerk[i]``; ``sb, vb, ab`` are the
    states at the breaks. After the last phase the motion continues with zero jerk (for a stop
    that is rest). Evaluation is vectorised over times.
    """

    __slots__ = ("durs", "jerks", "tb_l", "sb_l", "vb_l", "ab_l", "duration", "end", "_np")

    def __init__(
        self, s0: float, v0: float, a0: float, durs: list[float], jerks: list[float]
    ) -> None:
        self.durs = list(durs)
        self.jerks = list(jerks)
        tb = [0.0]
        sb, vb, ab = [s0], [v0], [a0]
        s, v, a, t = s0, v0, a0, 0.0
        for T, j in zip(durs, jerks, strict=True):
            s += T * (v + T * (0.5 * a + T * j / 6.0))
            v += T * (a + 0.5 * T * j)
            a += T * j
            t += T
            tb.append(t)
            sb.append(s)
            vb.append(v)
            ab.append(a)
        self.tb_l, self.sb_l, self.vb_l, self.ab_l = tb, sb, vb, ab
        self.duration = t
        self.end = (s, v, a)
        self._np: tuple[np.ndarray, ...] | None = None

    def _arrays(self) -> tuple[np.ndarray, ...]:
        if self._np is None:
            self._np = (
                np.array(self.tb_l),
                np.array(self.sb_l),
                np.array(self.vb_l),
                np.array(self.ab_l),
                np.array([*self.jerks, 0.0]),
            )
        return self._np

    @property
    def tb(self) -> np.ndarray:
        """Phase break times ``(P+1,)``."""
        return self._arrays()[0]

    @property
    def sb(self) -> np.ndarray:
        return self._arrays()[1]

    @property
    def vb(self) -> np.ndarray:
        return self._arrays()[2]

    @property
    def ab(self) -> np.ndarray:
        return self._arrays()[3]

    @property
    def jk(self) -> np.ndarray:
        """Jerk per phase, plus 0 after the end ``(P+1,)``."""
        return self._arrays()[4]

    @property
    def start(self) -> tuple[float, float, float]:
        return self.sb_l[0], self.vb_l[0], self.ab_l[0]

    def state_at(self, t: float) -> tuple[float, float, float]:
        s0, v0, a0 = self.start
        return phases_at(s0, v0, a0, self.durs, self.jerks, t)

    def evaluate(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(s, s', s'')`` at times ``t`` (any shape); times before 0 are clamped to 0."""
        tb, sb, vb, ab, jk = self._arrays()
        t = np.maximum(np.asarray(t, dtype=float), 0.0)
        i = np.searchsorted(tb, t, side="right") - 1
        np.minimum(i, len(self.durs), out=i)
        tau = t - tb[i]
        j = jk[i]
        a = ab[i]
        v = vb[i]
        s = sb[i] + tau * (v + tau * (0.5 * a + tau * j / 6.0))
        return s, v + tau * (a + 0.5 * tau * j), a + tau * j

    def tail(self, t0: float) -> ScalarProfile:
        """The same motion from time ``t0`` on, re-timed to start at 0."""
        s, v, a = self.state_at(t0)
        durs: list[float] = []
        jerks: list[float] = []
        acc = 0.0
        for T, j in zip(self.durs, self.jerks, strict=True):
            start, acc = acc, acc + T
            if acc > t0:
                durs.append(acc - max(start, t0))
                jerks.append(j)
        return ScalarProfile(s, v, a, durs, jerks)

    def then(self, other: ScalarProfile) -> ScalarProfile:
        """This profile's phases followed by ``other``'s (which should start at this end)."""
        s0, v0, a0 = self.start
        return ScalarProfile(s0, v0, a0, self.durs + other.durs, self.jerks + other.jerks)

    def interval_maxima(
        self, t: np.ndarray, v: np.ndarray, a: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Exact ``max s'`` and ``max |s''|`` over every ``[t_k, t_k+1]`` of sorted sample
        times ``t`` ``(K+1,)`` with ``v = s'(t)``, ``a = s''(t)`` already evaluated.

        ``s''`` is piecewise linear (extremes at the ends or at phase breaks) and ``s'`` is
        piecewise quadratic (extremes at the ends or where ``s'' = 0`` inside a phase).
        """
        vmax = np.maximum(v[:-1], v[1:])
        aa = np.abs(a)
        amax = np.maximum(aa[:-1], aa[1:])
        K = len(vmax)
        times: list[float] = []
        vals: list[float] = []
        is_v: list[bool] = []
        tb, vb, ab = self.tb_l, self.vb_l, self.ab_l
        for i, j in enumerate(self.jerks):
            if i > 0:
                times.append(tb[i])
                vals.append(abs(ab[i]))
                is_v.append(False)
            if j != 0.0:
                tau = -ab[i] / j
                if 0.0 < tau < self.durs[i]:
                    times.append(tb[i] + tau)
                    vals.append(vb[i] + tau * (ab[i] + 0.5 * tau * j))
                    is_v.append(True)
        if times:
            ks = np.searchsorted(t, times, side="right") - 1
            for k, val, flag in zip(ks.tolist(), vals, is_v, strict=True):
                if 0 <= k < K:
                    if flag:
                        if val > vmax[k]:
                            vmax[k] = val
                    elif val > amax[k]:
                        amax[k] = val
        return vmax, amax


# ----------------------------------------------------------------------------------------------
# Path


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
        if lin > _S_TOL * 1e-3:
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


def _dedupe(points: np.ndarray) -> np.ndarray:
    keep = [0]
    for i in range(1, len(points)):
        if np.linalg.norm(points[i] - points[keep[-1]]) > _S_TOL:
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
        self._tables: PathTables | None = None
        if pieces is None:
            self.length = 0.0
            self._s0_list: list[float] = [0.0]
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
        assert p is not None
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

    def _clipped(self, s_a: float, s_b: float) -> _Pieces | None:
        """The pieces over ``[s_a, s_b]``, re-based so ``s_a`` becomes 0."""
        p = self._p
        if p is None or s_b - s_a <= _S_TOL * 1e-3:
            return None
        k0, k1 = self.piece_index(s_a), self.piece_index(s_b)
        if k1 > k0 and s_b - self._s0_list[k1] <= _S_TOL * 1e-3:
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


# ----------------------------------------------------------------------------------------------
# Admissible path-speed boxes


class PathTables:
    """Per-piece data of a path under given limits, as Python floats for scalar hot loops.

    ``lin[k]``: piece ``k`` is straight; ``v_lin, a_lin, j_lin``: its exact path limits then;
    ``rows[k]``: per-joint tuples ``(M1, M2, M3, 1/M1, v_max, a_max, j_max)``.
    """

    __slots__ = ("source", "lim", "lin", "v_lin", "a_lin", "j_lin", "rows", "u", "dl")

    def __init__(self, path: PathTrajectory, limits: JointLimits) -> None:
        self.source = limits
        lim = limit_arrays(limits, path.n_joints)
        self.lim = lim
        self.lin: list[bool] = []
        self.v_lin: list[float] = []
        self.a_lin: list[float] = []
        self.j_lin: list[float] = []
        self.rows: list[list[tuple[float, ...]]] = []
        self.u: list[list[float]] = []
        self.dl: list[list[float]] = []
        if path.n_pieces == 0 or path._p is None:
            return
        self.u = path._p.u.tolist()
        self.dl = path._p.dl.tolist()
        with np.errstate(divide="ignore", invalid="ignore"):
            v_lin = np.min(lim.v * path.invM1, axis=1)
            a_lin = np.min(lim.a * path.invM1, axis=1)
            j_lin = np.min(lim.j * path.invM1, axis=1)
        self.v_lin = [float(x) for x in v_lin]
        self.a_lin = [float(x) for x in a_lin]
        self.j_lin = [float(x) for x in j_lin]
        self.lin = [
            bool(x) for x in (np.max(path.M2, axis=1) == 0) & (np.max(path.M3, axis=1) == 0)
        ]
        cols = (lim.v, lim.a, lim.j)
        for k in range(path.n_pieces):
            self.rows.append(
                list(
                    zip(
                        path.M1[k].tolist(),
                        path.M2[k].tolist(),
                        path.M3[k].tolist(),
                        path.invM1[k].tolist(),
                        *(c.tolist() for c in cols),
                        strict=True,
                    )
                )
            )


def path_tables(path: PathTrajectory, limits: JointLimits) -> PathTables:
    """:class:`PathTables` of ``path`` under ``limits`` (cached on the path per limits object)."""
    cached = getattr(path, "_tables", None)
    if cached is not None and cached.source is limits:
        return cached
    tables = PathTables(path, limits)
    path._tables = tables
    return tables


def piece_room(tab: PathTables, k: int, w: float, am: float) -> tuple[float, float]:
    """``(A, J)`` room on piece ``k`` at path speed <= ``w`` and ``|s''|`` <= ``am``:
    ``min_j (a_j - M2 w^2) / M1`` and ``min_j (j_j - M3 w^3 - 3 M2 w am) / M1``;
    ``(-1, -1)`` if the speed alone breaks a joint velocity limit."""
    if tab.lin[k]:
        if w > tab.v_lin[k]:
            return -1.0, -1.0
        return tab.a_lin[k], tab.j_lin[k]
    w2 = w * w
    w3 = w2 * w
    A = math.inf
    J = math.inf
    for m1, m2, m3, im1, vj, aj, jj in tab.rows[k]:
        if m1 * w > vj:
            return -1.0, -1.0
        ar = (aj - m2 * w2) * im1
        jr = (jj - m3 * w3 - 3.0 * m2 * w * am) * im1
        if ar < A:
            A = ar
        if jr < J:
            J = jr
    return A, J


def sub_piece_room(
    path: PathTrajectory, tab: PathTables, k: int, sa: float, sb: float, w: float, am: float
) -> tuple[float, float]:
    """:func:`piece_room` with the maxima of ``|q'|``, ``|q''|``, ``|q'''|`` taken over
    ``[sa, sb]`` inside piece ``k`` only. The extremes are exact: along a blend ``q'`` is
    monotone, ``h'`` is concave with its peak at the middle and ``h''`` is linear."""
    if tab.lin[k]:
        return piece_room(tab, k, w, am)
    s0 = path._s0_list[k]
    x_lo, x_hi = path._x0_list[k], path._x1_list[k]
    iL = path._invL_list[k]
    xa = min(max(x_lo + (sa - s0) * iL, x_lo), x_hi)
    xb = min(max(x_lo + (sb - s0) * iL, xa), x_hi)
    ha, hb = xa * xa * (3.0 - 2.0 * xa), xb * xb * (3.0 - 2.0 * xb)
    xm = min(max(0.5, xa), xb)
    dh = 6.0 * xm * (1.0 - xm) * iL
    ddh = max(abs(6.0 - 12.0 * xa), abs(6.0 - 12.0 * xb)) * iL * iL
    w2 = w * w
    w3 = w2 * w
    A = math.inf
    J = math.inf
    for (_, _, _, _, vj, aj, jj), uj, dj in zip(tab.rows[k], tab.u[k], tab.dl[k], strict=True):
        m1 = max(abs(uj + ha * dj), abs(uj + hb * dj))
        adj = abs(dj)
        m2 = adj * dh
        if m1 * w > vj:
            return -1.0, -1.0
        if m1 > 0.0:
            ar = (aj - m2 * w2) / m1
            jr = (jj - adj * ddh * w3 - 3.0 * m2 * w * am) / m1
            if ar < A:
                A = ar
            if jr < J:
                J = jr
    return A, J


def piece_boxes(
    path: PathTrajectory, lim: _LimitArrays, tangential_share: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(V, A, J)`` per piece: path speed, acceleration and jerk limits that keep every joint
    within its limits on that piece (see the module notes)."""
    M1, M2, M3 = path.M1, path.M2, path.M3
    iM1 = path.invM1
    rho = tangential_share
    with np.errstate(divide="ignore", invalid="ignore"):
        v_vel = np.min(np.where(M1 > 0, lim.v / np.where(M1 > 0, M1, 1.0), np.inf), axis=1)
        v_acc = np.min(
            np.where(M2 > 0, np.sqrt((1 - rho) * lim.a / np.where(M2 > 0, M2, 1.0)), np.inf),
            axis=1,
        )
        a_lin = np.min(lim.a * iM1, axis=1)
        # jerk: M3 V^3 + 3 M2 a_lin V <= (1 - rho) j, per joint; unique positive root of a
        # cubic with non-negative coefficients (stable Cardano form, then two Newton steps)
        c3 = M3
        c1 = 3.0 * M2 * a_lin[:, None]
        r = (1 - rho) * lim.j
        v_j = np.full(M1.shape, np.inf)
        lin_only = (c3 == 0) & (c1 > 0)
        v_j = np.where(lin_only, r / np.where(c1 > 0, c1, 1.0), v_j)
        cub = c3 > 0
        c3s = np.where(cub, c3, 1.0)
        pp = c1 / c3s
        qq = r / c3s
        disc = np.sqrt(0.25 * qq * qq + pp**3 / 27.0)
        aa = np.cbrt(0.5 * qq + disc)
        bb = np.cbrt(disc - 0.5 * qq)
        root = qq / (aa * aa + aa * bb + bb * bb)
        for _ in range(2):
            f = root**3 + pp * root - qq
            root = root - f / (3.0 * root * root + pp)
        v_j = np.where(cub, root, v_j)
    V = np.minimum(np.minimum(v_vel, v_acc), np.min(v_j, axis=1))
    V = V * (1.0 - LIMIT_MARGIN)
    A = np.min((lim.a - M2 * (V * V)[:, None]) * iM1, axis=1)
    A = np.maximum(A, 0.0) * (1.0 - LIMIT_MARGIN)
    J = np.min((lim.j - M3 * (V**3)[:, None] - 3.0 * M2 * (V * A)[:, None]) * iM1, axis=1)
    J = J * (1.0 - LIMIT_MARGIN)
    if np.any(A <= 0) or np.any(J <= 0) or np.any(V <= 0):  # pragma: no cover - by construction
        raise RobotModelError("path has a piece with no admissible path speed; check the limits")
    return V, A, J


# ----------------------------------------------------------------------------------------------
# Follower


@dataclass(frozen=True)
class FollowerStep:
    """One planned control step of a :class:`PathFollower` (nothing mutated until committed).

    ``profile``: the path motion ``s(t)`` over ``[0, dt]`` from the follower's state;
    ``end``: ``(s, s', s'')`` at ``dt``; ``stop``: the failsafe from ``end`` (valid);
    ``fallback``: True when the intended motion could not be verified and the step is the first
    ``dt`` of the failsafe the follower already held.
    """

    dt: float
    path: PathTrajectory
    profile: ScalarProfile
    end: tuple[float, float, float]
    stop: StopProfile
    fallback: bool


class PathFollower:
    """Online jerk-limited follower of a :class:`PathTrajectory` under :class:`JointLimits`.

    ``path_or_waypoints``: a path, or waypoints ``(W, n)`` to build one. The follower starts at
    rest at ``s = 0``. ``s``, ``sd`` (s'), ``sdd`` (s'') expose the path state; ``state`` the
    joint state; ``stop`` the failsafe the follower currently holds (a valid path-consistent
    stop from the current state). See the module notes for the planning scheme.
    """

    def __init__(
        self,
        path_or_waypoints: PathTrajectory | object,
        limits: JointLimits,
        *,
        blend_distance: float = 0.1,
        tangential_share: float = 0.5,
    ) -> None:
        from sara_app.robot.failsafe import plan_stop, rest_stop

        self._plan_stop = plan_stop
        self._rest_stop = rest_stop
        if not (0.0 < tangential_share < 1.0):
            raise RobotModelError(
                f"tangential_share = {tangential_share!r}; expected a fraction in (0, 1)"
            )
        self.limits = limits
        self.tangential_share = float(tangential_share)
        if isinstance(path_or_waypoints, PathTrajectory):
            path = path_or_waypoints
            n = path.n_joints
            lim = limit_arrays(limits, n)
            check_waypoints(path.waypoints, limits, n)
            self.blend_distance = path.blend_distance
        else:
            path = PathTrajectory(path_or_waypoints, blend_distance=blend_distance, limits=limits)
            lim = limit_arrays(limits, path.n_joints)
            self.blend_distance = float(blend_distance)
        self._lim = lim
        self._t = 0.0
        self._cap = math.inf
        self.fallback_steps = 0
        self._pending: np.ndarray | None = None
        self._goal: np.ndarray | None = None
        self._set_path(path, 0.0, 0.0, 0.0, None)

    # -- state ---------------------------------------------------------------------------------

    def _set_path(
        self, path: PathTrajectory, s: float, v: float, a: float, stop: StopProfile | None
    ) -> None:
        self.path = path
        self._S = path.length
        self._s, self._v, self._a = s, v, a
        if path.n_pieces:
            V, A, J = piece_boxes(path, self._lim, self.tangential_share)
            self._V = [float(x) for x in V]
            self._A = [float(x) for x in A]
            self._J = [float(x) for x in J]
            self._A_min = min(self._A)
            self._A_top = max(self._A)
            self._J_min = min(self._J)
            # smallest box from each piece to the end of the path
            self._A_tail = np.minimum.accumulate(A[::-1])[::-1].tolist()
            self._J_tail = np.minimum.accumulate(J[::-1])[::-1].tolist()
        else:
            self._V, self._A, self._J = [], [], []
        self._stop = stop if stop is not None else self._rest_stop(path, s)

    @property
    def s(self) -> float:
        """Path coordinate (rad)."""
        return self._s

    @property
    def sd(self) -> float:
        """Path speed s' (rad/s)."""
        return self._v

    @property
    def sdd(self) -> float:
        """Path acceleration s'' (rad/s^2)."""
        return self._a

    @property
    def t(self) -> float:
        """Time followed so far (s)."""
        return self._t

    @property
    def stop(self) -> StopProfile:
        """The failsafe held for the current state (valid, path-consistent)."""
        return self._stop

    @property
    def speed_cap(self) -> float:
        """Upper bound on the path speed s' the intended motion aims for (rad/s; default inf).

        The intended motion targets ``min(V_k, speed_cap)`` on the current and every upcoming
        piece ``k`` (``V_k``: the piece's admissible speed), so below the current speed it
        decelerates within the path's acceleration and jerk boxes; every step is still checked
        against the joint limits and ends with a valid failsafe, whatever the cap. It steers
        planning only: the failsafe held is never changed. 0 brings the robot to rest along the
        intended motion (not ``done``: raising the cap resumes)."""
        return self._cap

    @speed_cap.setter
    def speed_cap(self, cap: float) -> None:
        try:
            c = float(cap)
        except (TypeError, ValueError):
            c = math.nan
        if not c >= 0.0:  # NaN too
            raise RobotModelError(f"speed_cap = {cap!r} rad/s; expected a path speed >= 0 or inf")
        self._cap = c

    @property
    def admissible_speed(self) -> tuple[np.ndarray, np.ndarray]:
        """``(piece starts, V)``: the precomputed admissible path speed, piecewise constant."""
        return self.path.piece_starts, np.array(self._V)

    @property
    def done(self) -> bool:
        """At rest at the end of the path."""
        return self._S - self._s <= _S_TOL and self._v <= _REST_V and abs(self._a) <= _REST_A

    @property
    def state(self) -> JointState:
        q, dq, d2q = self.path.derivatives(self._s, 2)
        v = dq * self._v
        return JointState(q=q, v=v, a=d2q * self._v**2 + dq * self._a)

    def copy(self) -> PathFollower:
        other = PathFollower.__new__(PathFollower)
        other.__dict__.update(self.__dict__)
        return other

    # -- planning ------------------------------------------------------------------------------

    def _brake_gap(
        self, base: tuple[list[float], list[float]], tau: float, target: float, A: float, J: float
    ) -> float:
        """Where a brake to ``target`` started at ``tau`` on ``base`` ends, in s."""
        s, v, a = phases_at(self._s, self._v, self._a, base[0], base[1], tau)
        d, j = velocity_phases(v, a, target, A, J)
        return phases_end(s, v, a, d, j)[0]

    def _fit_brake(
        self,
        base: tuple[list[float], list[float]],
        dt: float,
        target: float,
        pos: float,
        A: float,
        J: float,
    ) -> tuple[float, tuple[list[float], list[float]]]:
        """Latest start ``tau`` in ``[0, dt]`` of a brake to ``target`` that ends by ``pos``."""
        lo, hi = 0.0, dt
        if self._brake_gap(base, 0.0, target, A, J) >= pos:
            tau = 0.0
        else:
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                if self._brake_gap(base, mid, target, A, J) < pos:
                    lo = mid
                else:
                    hi = mid
                if hi - lo <= 1e-12 * dt:
                    break
            tau = lo
        s, v, a = phases_at(self._s, self._v, self._a, base[0], base[1], tau)
        d, j = velocity_phases(v, a, target, A, J)
        bd, bj = _cut(base[0], base[1], tau) if tau > 0 else ([], [])
        return tau, (bd + d, bj + j)

    def _intended(self, dt: float) -> tuple[list[float], list[float], float, float]:
        """Phases of the intended motion from the current state, and the path limits used."""
        s, v, a = self._s, self._v, self._a
        S = self._S
        A_box, J_box, V_box = self._A, self._J, self._V
        k0 = self.path.piece_index(s)
        # look-ahead: any stop from here with the smallest box of the path, and a shorter
        # window in which an acceleration must already fit the box (time to ramp it down)
        Ag, Jg = self._A_min, self._J_min
        d, j = velocity_phases(v, a, 0.0, Ag, Jg) if v > 0 or a != 0 else ([], [])
        reach = max(phases_end(0.0, v, a, d, j)[0], 0.0) if d else 0.0
        ramp = (abs(v) + abs(a) * dt) * (2.0 * self._A_top / Jg + 2.0 * dt)
        kr = self.path.piece_index(min(s + ramp + _S_TOL, S))
        kw = self.path.piece_index(min(s + reach + ramp + _S_TOL, S))
        A_f = min(A_box[k0 : kr + 1])
        J_f = min(J_box[k0 : kr + 1])
        cap = self._cap
        base = velocity_phases(v, a, min(V_box[k0], cap), A_f, J_f)
        s1, v1, a1 = phases_at(s, v, a, base[0], base[1], dt)
        # constraints ahead: reach the admissible speed of every slower piece by its start,
        # braking within the boxes of the pieces up to it; standstill at the end of the path
        cons: list[tuple[float, float, float, float]] = []
        A_run, J_run = A_f, J_f
        for k in range(k0 + 1, kw + 1):
            A_run = min(A_run, A_box[k])
            J_run = min(J_run, J_box[k])
            V_k = min(V_box[k], cap)
            if V_k < v1 + max(a1, 0.0) ** 2 / (2.0 * J_run):
                cons.append((self._path_s0(k), V_k, A_run, J_run))
        if S - s <= reach + ramp + _S_TOL:
            cons.append((S, 0.0, min(A_f, self._A_tail[k0]), min(J_f, self._J_tail[k0])))
        # of the brakes needed now, the one that slows down most within this step satisfies
        # the others too (they brake later or less)
        best: tuple[tuple[float, float], tuple[list[float], list[float]], float, float] | None
        best = None
        for pos, target, A_c, J_c in cons:
            dd, jj = velocity_phases(v1, a1, target, A_c, J_c)
            if phases_end(s1, v1, a1, dd, jj)[0] >= pos - _S_TOL * 1e-3:
                _, plan = self._fit_brake(base, dt, target, pos, A_c, J_c)
                _, v_end, a_end = phases_at(s, v, a, plan[0], plan[1], dt)
                if best is None or (v_end, a_end) < best[0]:
                    best = ((v_end, a_end), plan, A_c, J_c)
        if best is not None:
            return best[1][0], best[1][1], best[2], best[3]
        return base[0], base[1], A_f, J_f

    def _path_s0(self, k: int) -> float:
        return self.path._s0_list[k]

    def _step_ok(self, prof: ScalarProfile, s1: float) -> bool:
        """Joint limits hold over the step (rigorous: piece maxima and profile maxima, taken
        per piece over the part of the step spent in it)."""
        s0, v0, a0 = prof.start
        k0, k1 = self.path.piece_index(s0), self.path.piece_index(s1)
        if k1 == k0:
            return self._piece_ok(k0, *phase_maxima(v0, a0, prof.durs, prof.jerks))
        T = prof.duration
        t_in = 0.0
        for k in range(k0, k1 + 1):
            if k < k1:  # leaves piece k inside the step: bracket the crossing time
                b = self.path._s0_list[k + 1]
                lo, hi = t_in, T
                for _ in range(60):
                    mid = 0.5 * (lo + hi)
                    if prof.state_at(mid)[0] < b:
                        lo = mid
                    else:
                        hi = mid
                    if hi - lo <= 1e-15:
                        break
                t_out, t_next = hi, lo  # piece k up to hi at most, piece k+1 from lo at least
            else:
                t_out, t_next = T, T
            part = prof.tail(t_in)
            durs, jerks = _cut(part.durs, part.jerks, max(t_out - t_in, 0.0))
            sv = part.start
            if not self._piece_ok(k, *phase_maxima(sv[1], sv[2], durs, jerks)):
                return False
            t_in = t_next
        return True

    def _piece_ok(self, k: int, vmax: float, amax: float, jmax: float) -> bool:
        """Joint limits hold on piece ``k`` at path speed, acceleration, jerk up to these."""
        if vmax <= self._V[k] and amax <= self._A[k] and jmax <= self._J[k]:
            return True
        p = self.path
        lim = self._lim
        M1, M2, M3 = p.M1[k], p.M2[k], p.M3[k]
        return bool(
            np.all(M1 * vmax <= lim.v)
            and np.all(M2 * vmax**2 + M1 * amax <= lim.a)
            and np.all(M3 * vmax**3 + 3 * M2 * vmax * amax + M1 * jmax <= lim.j)
        )

    def peek(self, dt: float) -> FollowerStep:
        """Plan one control step of ``dt`` seconds without changing the follower."""
        if not (isinstance(dt, int | float) and math.isfinite(dt) and dt > 0):
            raise RobotModelError(f"dt = {dt!r} s; expected a finite time step > 0")
        dt = float(dt)
        s, v, a = self._s, self._v, self._a
        if self.done or self.path.n_pieces == 0:
            prof = ScalarProfile(s, 0.0, 0.0, [dt], [0.0])
            return FollowerStep(dt, self.path, prof, (s, 0.0, 0.0), self._stop, False)
        durs, jerks, A_f, J_f = self._intended(dt)
        d, j = _cut(durs, jerks, dt)
        prof = ScalarProfile(s, v, a, d, j)
        s1, v1, a1 = prof.end
        if abs(v1) <= 1e-12 and abs(a1) <= 1e-9:
            v1, a1 = max(v1, 0.0), 0.0
        if self._S - s1 <= _S_TOL and v1 <= _REST_V:
            s1 = min(s1, self._S)
        if v1 >= 0.0 and s1 <= self._S + _S_TOL and self._step_ok(prof, s1):
            try:
                stop = self._plan_stop(self.path, s1, v1, a1, self.limits, hint=(A_f, J_f))
            except RobotModelError:
                stop = None
            if stop is not None:
                return FollowerStep(dt, self.path, prof, (s1, v1, a1), stop, False)
        # fallback: the failsafe already held
        held = self._stop
        d, j = _cut(held.profile.durs, held.profile.jerks, dt)
        prof = ScalarProfile(s, v, a, d, j)
        return FollowerStep(dt, self.path, prof, prof.end, held.advanced(dt), True)

    def commit(self, step: FollowerStep, at_end: JointState | None = None) -> JointState:
        """Apply a step from :meth:`peek` (of this follower, in its current state).

        ``at_end``: the joint state at the end of the step if the caller already sampled it
        (a shielded trajectory's sample 1); returned as is unless the path ends with this step.
        """
        if step.path is not self.path or step.profile.start != (self._s, self._v, self._a):
            raise RobotModelError(
                "step was planned for another path or state; call peek() again before commit()"
            )
        self._s, self._v, self._a = step.end
        self._stop = step.stop
        self._t += step.dt
        if step.fallback:
            self.fallback_steps += 1
        if self.done:
            self._s, self._v, self._a = self._S, 0.0, 0.0
            self._stop = self._rest_stop(self.path, self._S)
            pending = self._pending
            if pending is not None:
                self._pending = None
                self._start_from_rest(pending)
            return self.state
        return self.state if at_end is None else at_end

    def step(self, dt: float) -> JointState:
        """Advance ``dt`` seconds along the path; returns the joint state at the end."""
        return self.commit(self.peek(dt))

    def brake(self, dt: float) -> JointState:
        """Advance ``dt`` seconds along the failsafe held (the verified stop)."""
        held = self._stop
        d, j = _cut(held.profile.durs, held.profile.jerks, dt)
        prof = ScalarProfile(self._s, self._v, self._a, d, j)
        return self.commit(FollowerStep(dt, self.path, prof, prof.end, held.advanced(dt), True))

    # -- replanning ----------------------------------------------------------------------------

    def _start_from_rest(self, wps: np.ndarray) -> None:
        q_now = self.path.q(self._s)
        pts = np.vstack([q_now[None, :], wps])
        path = PathTrajectory(pts, blend_distance=self.blend_distance, limits=self.limits)
        self._set_path(path, 0.0, 0.0, 0.0, None)

    def replan(self, new_waypoints: object) -> None:
        """Continue through ``new_waypoints`` ``(W, n)`` from the current state without stopping.

        The new path keeps the current geometry over the stopping distance of the failsafe held
        (which therefore stays valid), runs straight on in the current direction to a corner,
        blended into the first new waypoint, and then through the others. If the robot is at
        rest the new path simply starts at the current position.
        """
        n = self.path.n_joints
        wps = check_waypoints(new_waypoints, self.limits, n)
        # a planner re-sending the same goal changes nothing
        goal = self._goal
        if goal is not None and goal.shape == wps.shape and np.array_equal(goal, wps):
            return
        self._goal = wps
        if len(wps) == 1 and np.linalg.norm(wps[0] - self.path.q(self._S)) <= _S_TOL:
            return
        self._pending = None
        if self._v <= _REST_V and abs(self._a) <= _REST_A:
            self._start_from_rest(wps)
            return
        path, stop = self.path, self._stop
        p = path._p
        assert p is not None
        # junction on a straight piece at or after the end of the held stop (the last piece of
        # a path is always straight)
        s_min = min(stop.s_end, self._S)
        k = path.piece_index(s_min)
        while p.blend[k] and k + 1 < path.n_pieces:
            k += 1
        s_b = max(s_min, self._path_s0(k))
        u = p.u[k]
        q_b = path.q(s_b)
        lim = self._lim
        with np.errstate(divide="ignore", invalid="ignore"):
            room_j = np.where(
                u > 0, (lim.q_max - q_b) / u, np.where(u < 0, (lim.q_min - q_b) / u, np.inf)
            )
        room = float(np.min(room_j))
        prefix = path._clipped(self._s, s_b)
        s_off = s_b - self._s
        q_now = path.q(self._s)
        # waypoints the held stop already ends on are reached
        first = 0
        while first < len(wps) and np.linalg.norm(wps[first] - q_b) <= 1e-6:
            first += 1
        rest = wps[first:]
        if len(rest) == 0:
            assert prefix is not None
            new_path = PathTrajectory._from_pieces(
                np.vstack([q_now[None, :], wps]), self.blend_distance, q_now, prefix
            )
            self._set_path(new_path, 0.0, self._v, self._a, stop.rebased(new_path, -self._s))
            return
        # the corner may not lie beyond half the way to the first new waypoint
        reach_w0 = 0.5 * float(np.linalg.norm(rest[0] - q_b))
        extra = 0.0
        for _ in range(4):
            # straight run-in along the current direction (inside the joint position box),
            # then the new corner; move the corner further while the follower could not slow
            # down to the corner's admissible speed before it
            run = min(self.blend_distance, room - extra, reach_w0 if extra == 0.0 else np.inf)
            if run < 1e-6:
                # the robot cannot go on straight far enough before a joint limit: finish the
                # held stop and start the new path from rest
                self._pending = wps
                return
            q_c = q_b + (extra + run) * u
            pts = _dedupe(np.vstack([q_b[None, :], q_c[None, :], rest]))
            tail = _polyline_pieces(pts, self.blend_distance, s_off, first_full=True)
            pieces = tail if prefix is None else _Pieces.concat([prefix, tail])
            new_path = PathTrajectory._from_pieces(
                np.vstack([q_now[None, :], wps]), self.blend_distance, q_now, pieces
            )
            corner = np.flatnonzero(pieces.blend & (pieces.s0 >= s_off - _S_TOL))
            if corner.size == 0:
                break
            kc = int(corner[0])
            V, A, J = piece_boxes(new_path, self._lim, self.tangential_share)
            A_w, J_w = float(A[: kc + 1].min()), float(J[: kc + 1].min())
            d, j = velocity_phases(self._v, self._a, float(V[kc]), A_w, J_w)
            reach = phases_end(0.0, self._v, self._a, d, j)[0]
            free = float(pieces.s0[kc])
            if reach <= free:
                break
            if extra == 0.0 and self._S - s_min <= self.blend_distance:
                # already braking to a standstill near the end of the current path, too close
                # to turn: finish the path and start the new one from rest
                self._pending = wps
                return
            extra += reach - free + 1e-6
        self._set_path(new_path, 0.0, self._v, self._a, stop.rebased(new_path, -self._s))

    # -- offline time-scaling --------------------------------------------------------------------

    def rollout(
        self, dt: float, t_max: float, sample_dt: float | None = None
    ) -> tuple[np.ndarray, ...]:
        """Step until done (or ``t_max``); returns dense samples ``(t, s, sd, sdd)``.

        ``sample_dt`` (default ``dt``) must divide ``dt``: the committed motion is sampled
        inside every step.
        """
        sub = 1 if sample_dt is None else max(1, int(round(dt / sample_dt)))
        local = np.arange(sub) * (dt / sub)
        ts, ss, vs, as_ = [], [], [], []
        while not self.done and self._t < t_max - 1e-12:
            st = self.peek(dt)
            s, v, a = st.profile.evaluate(local)
            ts.append(self._t + local)
            ss.append(s)
            vs.append(v)
            as_.append(a)
            self.commit(st)
        ts.append(np.array([self._t]))
        ss.append(np.array([self._s]))
        vs.append(np.array([self._v]))
        as_.append(np.array([self._a]))
        return tuple(np.concatenate(x) for x in (ts, ss, vs, as_))


def time_scaling(
    path: PathTrajectory, limits: JointLimits, dt: float = 1e-3, t_max: float = 600.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Offline time-scaling of ``path`` from rest to rest: samples ``(t, s, s', s'')`` every
    ``dt`` seconds, produced by a :class:`PathFollower` (same limits and guarantees)."""
    t, s, sd, sdd = PathFollower(path, limits).rollout(dt, t_max)
    return t, s, sd, sdd
