"""Failsafe stops and the shielded trajectory (one intended step + a failsafe to standstill).

Path-consistent stop (production: the compiled planner, :mod:`sara_app.robot.planning_kernels`;
its plain-Python reference, ``plan_stop``, lives in ``tests/stop_reference.py``). From a path state
``(s, s', s'')`` the path speed is brought to zero with the time-optimal jerk-limited scalar
profile (jerk ``-J`` until ``s''`` reaches ``-A`` or a peak, an optional constant-``s''`` phase,
jerk ``+J`` so that ``s''`` and ``s'`` reach zero together). The joints follow ``q(s(t))``, so the
stop stays on the path and ``s`` is monotone. ``A`` and ``J`` are chosen so that every joint stays
within its limits over the whole stretch of path the stop covers, using ``v = q' s'``, ``a = q''
s'^2 + q' s''`` and ``j = q''' s'^3 + 3 q'' s' s'' + q' s'''`` with, for every path piece ``k`` the
stop touches, the per-joint maxima ``M1, M2, M3`` of ``|q'|, |q''|, |q'''|`` over the piece and a
bound ``w_k`` on the path speed while the stop is in that piece::

    M1 w_k <= v_max,   M2 w_k^2 + M1 max|s''| <= a_max,
    M3 w_k^3 + 3 M2 w_k max|s''| + M1 J <= j_max          (every joint, every piece)

``w_k`` is the peak speed for the piece the stop starts in (and for any piece reached before the
speed peak), and otherwise the speed at the time the stop enters the piece, bracketed from below
by Newton's method (after the peak ``s`` is concave, so the iterates never pass the crossing, and
the speed only decreases from then on); ``max|s''|`` is likewise taken from the entry on (``s''``
is piecewise linear). For the first and the last piece the maxima ``M1, M2, M3`` are taken over
the covered part only (exact: along a blend ``q'`` is monotone, ``h'`` concave, ``h''`` linear).
``A`` and ``J`` start from the exact limits of the current piece and are lowered (fixed-point
iteration, at most eight rounds) until the conditions hold for the profile they produce; a hint
(the follower's own limits) is tried as well and the faster valid stop is kept.

How far from time-optimal: where the stop stays on a straight stretch (``M2 = M3 = 0``) the
conditions are exactly the path's limits (``|s''| <= min_j a_j / |u_j|``, and the same for the
jerk) and the stop IS the time-optimal path-consistent stop (``straight_line_stop_duration``,
equal to 1e-8 in the tests). Through blends the worst-case decoupling above (one ``(A, J)`` for
the whole stop, piece maxima at the peak speed) is conservative. Measured against a jerk-free
reference that decelerates as hard as the joint accelerations allow at every point of the path
(``tests/test_failsafe.py``, 90 degree corner, ``d = 0.1`` rad): straight stretches 1.00 to 1.26
times the reference (median 1.01; the excess is the jerk ramps), stops that start in or reach
the blend 1.1 to 6.1 times (median 3.3).

Joint-space stop (:func:`plan_joint_stop`), for a robot off any path: if velocity and
acceleration are parallel (straight-line motion) it is the time-optimal stop along that straight
line (path-consistent); otherwise every joint brakes with its own time-optimal jerk-limited
profile, re-timed (lower constant-acceleration plateau, same jerk limit) to end with the slowest
joint where the joint's state allows it.

Shielded trajectory (:func:`shielded_trajectory`): the follower's next step (planned without
changing the follower) then the failsafe from the end of that step, sampled at ``K + 1`` times,
with per-interval bounds on ``|v_j|`` and ``|a_j|`` for occupancy enlargement. The bounds are
rigorous: ``|v_j(t)| <= max|dq_j/ds| over the interval's s-range * max s'`` over the interval,
with ``dq_j/ds`` monotone on every piece (exact maximum from the ends and the piece starts) and
``s'`` piecewise quadratic (exact maximum from the ends and the zeros of ``s''``);
``|a_j| <= M2 max s'^2 + M1 max|s''|`` with piece maxima.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from sara_app.errors import RobotModelError
from sara_app.kernel_types import RO1 as _RO1
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import W2 as _W2
from sara_app.robot.joints import LIMIT_MARGIN, REST_A, REST_V, limit_arrays
from sara_app.robot.model import JointLimits
from sara_app.robot.path import PathTrajectory
from sara_app.robot.profile import ScalarProfile, phases_end, velocity_phases

__all__ = [
    "BOUND_PAD",
    "JointStopProfile",
    "StopProfile",
    "interval_bounds",
    "plan_joint_stop",
    "rest_stop",
]

BOUND_PAD = 1e-12
"""Relative padding of the interval bounds against rounding."""


def _finite(name: str, x: object) -> float:
    try:
        f = float(x)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise RobotModelError(f"{name} = {x!r}; expected a finite number") from None
    if not math.isfinite(f):
        raise RobotModelError(f"{name} = {x!r}; expected a finite number")
    return f


# ----------------------------------------------------------------------------------------------
# Path-consistent stop


class StopProfile:
    """A path-consistent stop: ``s(t)`` from ``s_start`` to ``s_end`` over ``duration_s``.

    ``A``, ``J``: the path acceleration and jerk limits it was planned with (0 for rest).
    """

    def __init__(self, path: PathTrajectory, profile: ScalarProfile, A: float, J: float) -> None:
        self.path = path
        self.profile = profile
        self.A = A
        self.J = J
        self.duration_s = profile.duration
        self.s_start = profile.sb_l[0]
        self.s_end = profile.end[0]

    def path_samples(self, times: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(s, s', s'')`` at ``times`` (s, from the start of the stop; rest after its end)."""
        return self.profile.evaluate(np.asarray(times, dtype=float))

    def sample(self, times: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint ``(q, v, a)``, each ``(K, n)``, at ``times`` ``(K,)``."""
        s, sd, sdd = self.path_samples(times)
        q, dq, d2q = self.path.derivatives(s, 2)
        v = dq * sd[..., None]
        a = d2q * (sd * sd)[..., None] + dq * sdd[..., None]
        return q, v, a

    def velocity_bounds(self, times: object) -> np.ndarray:
        """Rigorous ``max |v_j|`` over every interval between consecutive sorted ``times``,
        ``(K-1, n)``."""
        t = np.asarray(times, dtype=float)
        s, sd, sdd = self.profile.evaluate(t)
        dq = self.path.derivatives(s, 1)[1]
        return interval_bounds(self.path, self.profile, t, s, sd, sdd, dq)[0]

    def advanced(self, dt: float) -> StopProfile:
        """The rest of this stop after ``dt`` seconds (still a valid stop)."""
        return StopProfile(self.path, self.profile.tail(dt), self.A, self.J)

    def rebased(self, path: PathTrajectory, ds: float) -> StopProfile:
        """The same stop on ``path`` whose coordinate is this one's plus ``ds`` (same geometry)."""
        s0, v0, a0 = self.profile.start
        prof = ScalarProfile(s0 + ds, v0, a0, self.profile.durs, self.profile.jerks)
        return StopProfile(path, prof, self.A, self.J)


def rest_stop(path: PathTrajectory, s: float) -> StopProfile:
    """The trivial stop of a robot already at rest at ``s``."""
    return StopProfile(path, ScalarProfile(float(s), 0.0, 0.0, [], []), 0.0, 0.0)


# ----------------------------------------------------------------------------------------------
# Joint-space stop (off any path)


_Phases = tuple[list[float], list[float]]


def _retimed_stop(v0: float, a0: float, T: float, J: float, A: float) -> _Phases | None:
    """Phases from ``(v0, a0)`` to rest in exactly ``T`` with jerk ``J`` and one plateau."""
    vr = v0 + a0 * abs(a0) / (2.0 * J)
    if vr == 0.0:
        return None
    d = 1.0 if vr < 0.0 else -1.0  # direction of the velocity change
    ap = d * a0
    dv = -d * v0
    c = J * T + ap
    disc = c * c - 2.0 * ap * ap - 4.0 * J * dv
    out: _Phases | None = None
    if disc >= 0.0:
        p = 0.5 * (c - math.sqrt(disc))
        hold = T - (2.0 * p - ap) / J
        if p >= max(ap, 0.0) and hold >= 0.0 and p <= A:
            out = ([(p - ap) / J, hold, p / J], [d * J, 0.0, -d * J])
    if out is None and ap > 0.0:
        hold = T - ap / J
        if hold > 0.0:
            p = (dv - ap * ap / (2.0 * J)) / hold
            if 0.0 <= p <= ap:
                out = ([(ap - p) / J, hold, p / J], [-d * J, 0.0, -d * J])
    if out is None:
        return None
    _, v_end, a_end = phases_end(0.0, v0, a0, *out)
    if abs(v_end) > 1e-9 * (1.0 + abs(v0)) or abs(a_end) > 1e-7 * (1.0 + abs(a0)):
        return None
    return out


class JointStopProfile:
    """A joint-space stop: per-joint piecewise-constant-jerk profiles, at rest after
    ``duration_s``. ``straight``: True when it is the stop along a straight line."""

    def __init__(
        self,
        q0: np.ndarray,
        v0: np.ndarray,
        a0: np.ndarray,
        phases: list[_Phases],
        straight: bool,
    ) -> None:
        n = len(q0)
        P = max(1, max(len(p[0]) for p in phases))
        tb = np.zeros((n, P + 1))
        jk = np.zeros((n, P + 1))
        qb = np.zeros((n, P + 1))
        vb = np.zeros((n, P + 1))
        ab = np.zeros((n, P + 1))
        for i, (durs, jerks) in enumerate(phases):
            q, v, a, t = float(q0[i]), float(v0[i]), float(a0[i]), 0.0
            qb[i, 0], vb[i, 0], ab[i, 0] = q, v, a
            for m in range(P):
                T = durs[m] if m < len(durs) else 0.0
                j = jerks[m] if m < len(durs) else 0.0
                jk[i, m] = j
                q += T * (v + T * (0.5 * a + T * j / 6.0))
                v += T * (a + 0.5 * T * j)
                a += T * j
                t += T
                tb[i, m + 1], qb[i, m + 1], vb[i, m + 1], ab[i, m + 1] = t, q, v, a
            # snap the end to exact rest
            vb[i, P], ab[i, P] = 0.0, 0.0
        self._tb, self._jk, self._qb, self._vb, self._ab = tb, jk, qb, vb, ab
        self.duration_s = float(tb[:, -1].max())
        self.straight = straight
        self.q_end = qb[:, -1].copy()

    def sample(self, times: object) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Joint ``(q, v, a)``, each ``(K, n)``, at ``times`` ``(K,)``."""
        t = np.maximum(np.atleast_1d(np.asarray(times, dtype=float)), 0.0)
        idx = (t[:, None, None] >= self._tb[None, :, 1:]).sum(axis=2)  # (K, n)
        rows = np.arange(self._tb.shape[0])[None, :]
        tau = t[:, None] - self._tb[rows, idx]
        j = self._jk[rows, idx]
        a = self._ab[rows, idx]
        v = self._vb[rows, idx]
        q = self._qb[rows, idx] + tau * (v + tau * (0.5 * a + tau * j / 6.0))
        return q, v + tau * (a + 0.5 * tau * j), a + tau * j

    def velocity_bounds(self, times: object) -> np.ndarray:
        """Rigorous ``max |v_j|`` over every interval between consecutive ``times``."""
        t = np.asarray(times, dtype=float)
        _, v, _ = self.sample(t)
        out = np.maximum(np.abs(v[:-1]), np.abs(v[1:]))
        # interior extremes of v_j: zeros of a_j inside a phase
        with np.errstate(divide="ignore", invalid="ignore"):
            tz = self._tb[:, :-1] - self._ab[:, :-1] / self._jk[:, :-1]
        ok = (self._jk[:, :-1] != 0) & (tz > self._tb[:, :-1]) & (tz < self._tb[:, 1:])
        if ok.any():
            i_j, i_p = np.nonzero(ok)
            tzz = tz[i_j, i_p]
            _, vz, _ = self.sample(tzz)
            vz = np.abs(vz[np.arange(len(tzz)), i_j])
            inside = (tzz[None, :] > t[:-1, None]) & (tzz[None, :] < t[1:, None])
            for col in np.unique(i_j):
                sel = i_j == col
                cand = np.where(inside[:, sel], vz[sel][None, :], 0.0).max(axis=1)
                out[:, col] = np.maximum(out[:, col], cand)
        return out * (1.0 + BOUND_PAD) + 1e-15


def plan_joint_stop(q: object, v: object, a: object, limits: JointLimits) -> JointStopProfile:
    """Stop every joint from ``(q, v, a)`` (arrays ``(n,)``) without a path (see module notes)."""
    arrs = []
    for name, x in (("q", q), ("v", v), ("a", a)):
        try:
            arr = np.array(x, dtype=float)
        except (TypeError, ValueError):
            raise RobotModelError(f"{name} = {x!r}; expected an array of joint values") from None
        arrs.append(arr)
    q0, v0, a0 = arrs
    n = q0.shape[0] if q0.ndim == 1 else -1
    for name, arr in (("q", q0), ("v", v0), ("a", a0)):
        if arr.ndim != 1 or arr.shape[0] != n or n < 1:
            raise RobotModelError(f"{name} has shape {arr.shape}; expected ({max(n, 1)},)")
        if not np.all(np.isfinite(arr)):
            j = int(np.flatnonzero(~np.isfinite(arr))[0])
            raise RobotModelError(f"{name}[{j}] = {arr[j]}; expected a finite value")
    lim = limit_arrays(limits, n)
    nv, na = float(np.linalg.norm(v0)), float(np.linalg.norm(a0))
    if nv <= REST_V and na <= REST_A:
        return JointStopProfile(q0, np.zeros(n), np.zeros(n), [([], [])] * n, True)
    u = v0 / nv if nv > REST_V else a0 / na
    sd, sdd = float(v0 @ u), float(a0 @ u)
    straight = np.linalg.norm(v0 - sd * u) <= 1e-9 * (1.0 + nv) and np.linalg.norm(
        a0 - sdd * u
    ) <= 1e-9 * (1.0 + na)
    au = np.abs(u)
    with np.errstate(divide="ignore"):
        A = float(np.min(np.where(au > 0, lim.a / np.where(au > 0, au, 1.0), np.inf)))
        J = float(np.min(np.where(au > 0, lim.j / np.where(au > 0, au, 1.0), np.inf)))
    A *= 1.0 - LIMIT_MARGIN
    J *= 1.0 - LIMIT_MARGIN
    if straight and not (sdd < 0.0 and sd < sdd * sdd / (2.0 * J)):
        durs, jerks = velocity_phases(max(sd, 0.0), sdd, 0.0, max(A, abs(sdd)), J)
        phases = [(durs, [j * ui for j in jerks]) for ui in u]
        return JointStopProfile(q0, max(sd, 0.0) * u, sdd * u, phases, True)
    per = []
    for i in range(n):
        Ai = float(lim.a[i]) * (1.0 - LIMIT_MARGIN)
        Ji = float(lim.j[i]) * (1.0 - LIMIT_MARGIN)
        per.append(velocity_phases(float(v0[i]), float(a0[i]), 0.0, max(Ai, abs(a0[i])), Ji))
    T = max(sum(p[0]) for p in per)
    phases = []
    for i, p in enumerate(per):
        if sum(p[0]) < T * (1.0 - 1e-12):
            Ai = float(lim.a[i]) * (1.0 - LIMIT_MARGIN)
            Ji = float(lim.j[i]) * (1.0 - LIMIT_MARGIN)
            r = _retimed_stop(float(v0[i]), float(a0[i]), T, Ji, max(Ai, abs(a0[i])))
            phases.append(r if r is not None else p)
        else:
            phases.append(p)
    return JointStopProfile(q0, v0, a0, phases, False)


# ----------------------------------------------------------------------------------------------
# Rigorous bounds between samples


def interval_bounds(
    path: PathTrajectory,
    prof: ScalarProfile,
    t: np.ndarray,
    s: np.ndarray,
    sd: np.ndarray,
    sdd: np.ndarray,
    dq: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-interval bounds ``(max |v_j|, max |a_j|)``, ``(K, n)`` each, from the samples."""
    vmax, amax = prof.interval_maxima(t, sd, sdd)
    D1, M1, M2 = path.interval_bounds(s, dq)
    K, n = D1.shape
    v_bound, a_bound = np.empty((2, K, n))
    _bounds_kernel(vmax, amax, D1, M1, M2, v_bound, a_bound)
    return v_bound, a_bound


@njit(types.void(_RO1, _RO1, _RO2, _RO2, _RO2, _W2, _W2), cache=True)
def _bounds_kernel(
    vmax: np.ndarray,
    amax: np.ndarray,
    D1: np.ndarray,
    M1: np.ndarray,
    M2: np.ndarray,
    v_bound: np.ndarray,
    a_bound: np.ndarray,
) -> None:
    """``v_bound = D1 max(s', 0)``, ``a_bound = M2 max(s', 0)^2 + M1 max|s''|``, both padded by
    ``BOUND_PAD`` (relative) and 1e-15 (absolute), per interval ``k`` and joint ``j``."""
    pad = 1.0 + BOUND_PAD
    for k in range(D1.shape[0]):
        vm = vmax[k]
        if vm < 0.0:  # NaN stays NaN
            vm = 0.0
        for j in range(D1.shape[1]):
            v_bound[k, j] = D1[k, j] * vm * pad + 1e-15
            a_bound[k, j] = (M2[k, j] * (vm * vm) + M1[k, j] * amax[k]) * pad + 1e-15


def _warm_up() -> None:
    """First-call dispatch of the compiled helper at import, not in a control loop."""
    z1, z2 = np.zeros(1), np.zeros((1, 1))
    _bounds_kernel(z1, z1, z2, z2, z2, np.empty((1, 1)), np.empty((1, 1)))


_warm_up()
