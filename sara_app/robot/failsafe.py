"""Failsafe stops and the shielded trajectory (one intended step + a failsafe to standstill).

Path-consistent stop (:func:`plan_stop`). From a path state ``(s, s', s'')`` the path speed is
brought to zero with the time-optimal jerk-limited scalar profile (jerk ``-J`` until ``s''``
reaches ``-A`` or a peak, an optional constant-``s''`` phase, jerk ``+J`` so that ``s''`` and
``s'`` reach zero together). The joints follow ``q(s(t))``, so the stop stays on the path and
``s`` is monotone. ``A`` and ``J`` are chosen so that every joint stays within its limits over
the whole stretch of path the stop covers, using ``v = q' s'``, ``a = q'' s'^2 + q' s''`` and
``j = q''' s'^3 + 3 q'' s' s'' + q' s'''`` with, for every path piece ``k`` the stop touches, the
per-joint maxima ``M1, M2, M3`` of ``|q'|, |q''|, |q'''|`` over the piece and a bound ``w_k`` on
the path speed while the stop is in that piece::

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
jerk) and the stop IS the time-optimal path-consistent stop (:func:`straight_line_stop_duration`,
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
from bisect import bisect_right

import numpy as np
from numba import njit, types

from sara_app.errors import RobotModelError
from sara_app.kernel_types import RO1 as _RO1
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import W2 as _W2
from sara_app.robot.joints import LIMIT_MARGIN, REST_A, REST_V, S_TOL, limit_arrays
from sara_app.robot.model import JointLimits
from sara_app.robot.path import (
    PathTables,
    PathTrajectory,
    path_tables,
    piece_room,
    sub_piece_room,
)
from sara_app.robot.profile import ScalarProfile, phases_end, velocity_phases

__all__ = [
    "BOUND_PAD",
    "JointStopProfile",
    "StopProfile",
    "interval_bounds",
    "plan_joint_stop",
    "plan_stop",
    "rest_stop",
    "straight_line_stop_duration",
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


def _entry_bounds(prof: ScalarProfile, b: float, t_pk: float, vp: float) -> tuple[float, float]:
    """Bounds on ``s'`` and ``|s''|`` from the time the stop reaches ``s = b`` on.

    The entry time is bracketed from below by Newton's method from the start of the phase
    that contains ``b``: after the speed peak ``s`` is concave, so every iterate stays at or
    before the crossing, and the speed there bounds the speed from then on (it only decreases
    after the peak). ``s''`` is piecewise linear: its extremes are at the entry or at breaks.
    """
    s, v, a = prof.start
    t0 = 0.0
    j = 0.0
    for T, j in zip(prof.durs, prof.jerks):
        s1 = s + T * (v + T * (0.5 * a + T * j / 6.0))
        if s1 >= b:
            break
        s, v, a = s1, v + T * (a + 0.5 * T * j), a + T * j
        t0 += T
    else:
        return 0.0, 0.0  # never reached
    tau = 0.0
    if t0 >= t_pk:
        for _ in range(12):
            f = s + tau * (v + tau * (0.5 * a + tau * j / 6.0)) - b
            fp = v + tau * (a + 0.5 * tau * j)
            if f >= 0.0 or fp <= 0.0:
                break
            step = -f / fp
            tau += step
            if step <= 1e-15 * (1.0 + tau):
                break
        over = s + tau * (v + tau * (0.5 * a + tau * j / 6.0)) - b
        if over > 0.0:  # rounding at convergence: step back below the crossing
            fp = v + tau * (a + 0.5 * tau * j)
            tau = max(tau - 2.0 * over / fp - 1e-15, 0.0) if fp > 0.0 else 0.0
            if s + tau * (v + tau * (0.5 * a + tau * j / 6.0)) > b:
                tau = 0.0  # the phase start is always a lower bound
    t_in = t0 + tau
    w = vp if t_in < t_pk else v + tau * (a + 0.5 * tau * j)
    am = abs(a + tau * j)
    tbs = prof.tb_l
    for i, x in enumerate(prof.ab_l):
        if i and tbs[i] >= t_in and abs(x) > am:
            am = abs(x)
    return w, am


def _check_candidate(
    path: PathTrajectory, tab: PathTables, s: float, v0: float, a0: float, A: float, J: float
) -> tuple[ScalarProfile | None, float, float]:
    """Profile for ``(A, J)`` and the limits its own speeds allow: ``(profile or None, A2, J2)``.

    The profile is returned only if it keeps every joint within its limits on every piece it
    covers; ``A2 = -1`` means no smaller ``(A, J)`` can help.
    """
    if A <= 0.0 or J <= 0.0:
        return None, -1.0, -1.0
    if a0 < 0.0 and v0 < a0 * a0 / (2.0 * J) * (1.0 - 1e-9) - 1e-15:
        return None, -1.0, -1.0  # would have to run backwards along the path
    durs, jerks = velocity_phases(v0, a0, 0.0, A, J)
    prof = ScalarProfile(s, v0, a0, durs, jerks)
    S = path.length
    s_end = prof.end[0]
    if s_end > S + S_TOL:
        return None, -1.0, -1.0  # runs off the end of the path
    if a0 > 0.0:
        t_pk = a0 / J
        vp = v0 + a0 * a0 / (2.0 * J)
    else:
        t_pk, vp = 0.0, v0
    # below, "if x > m: m = x" is max(m, x) and "if x < m: m = x" min(m, x), NaN included
    ab = prof.ab_l
    amax0 = abs(ab[0])
    for x in ab:
        x = abs(x)
        if x > amax0:
            amax0 = x
    starts = path._s0_list
    k0 = bisect_right(starts, s) - 1  # path.piece_index
    k1 = bisect_right(starts, S if S < s_end else s_end) - 1
    if k0 < 0:
        k0 = 0
    if k1 < 0:
        k1 = 0
    ok = True
    A2 = J2 = math.inf
    for k in range(k0, k1 + 1):
        if k == k0:
            w, am = vp, amax0
        else:
            w, am = _entry_bounds(prof, starts[k], t_pk, vp)
        if k == k0 or k == k1:  # partly covered pieces: maxima over the covered part only
            sa = s if k == k0 else starts[k]
            sb = s_end if k == k1 else starts[k + 1]
            Ak, Jk = sub_piece_room(path, tab, k, sa, sb, w, am)
        else:
            Ak, Jk = piece_room(tab, k, w, am)
        if Ak < 0.0 and Jk < 0.0:
            return None, -1.0, -1.0
        if am > Ak:
            ok = False
        if Ak < A2:
            A2 = Ak
        if Jk < J2:
            J2 = Jk
    ok = ok and J <= J2
    return (prof if ok else None), A2, J2


def plan_stop(
    path: PathTrajectory,
    s: float,
    sd: float,
    sdd: float,
    limits: JointLimits,
    *,
    hint: tuple[float, float] | None = None,
) -> StopProfile:
    """Near-time-optimal path-consistent stop from path state ``(s, s', s'')``.

    Raises :class:`RobotModelError` if no stop along the path keeps the joints within
    ``limits`` (for instance a state faster than the path allows, or a stop that would run
    past the end of the path). ``hint``: extra ``(A, J)`` path limits to try.
    """
    tab = path_tables(path, limits)
    return plan_stop_unchecked(
        path, tab, _finite("s", s), _finite("sd", sd), _finite("sdd", sdd), hint
    )


def plan_stop_unchecked(
    path: PathTrajectory,
    tab: PathTables,
    s: float,
    v0: float,
    a0: float,
    hint: tuple[float, float] | None,
) -> StopProfile:
    """:func:`plan_stop` from a finite float state ``(s, s', s'')`` and the path's tables."""
    S = path.length
    if s < -S_TOL or s > S + S_TOL:
        raise RobotModelError(f"s = {s!r} rad; expected a path coordinate in [0, {S:.6g}]")
    if v0 < -1e-12:
        raise RobotModelError(f"sd = {v0!r} rad/s; expected a path speed >= 0")
    # "0.0 if 0.0 > x else x" is max(x, 0.0) and "S if S < x else x" min(x, S), NaN included
    s = 0.0 if 0.0 > s else s
    s = S if S < s else s
    v0 = 0.0 if 0.0 > v0 else v0
    if v0 <= REST_V and abs(a0) <= REST_A:
        return rest_stop(path, s)
    if path.n_pieces == 0:
        raise RobotModelError(f"path of length 0 cannot move at sd = {v0!r}, sdd = {a0!r}")
    # first candidate: the exact limits of the current piece at the speed the stop can reach
    k0 = bisect_right(path._s0_list, s) - 1  # path.piece_index
    k0 = 0 if k0 < 0 else k0
    w = v0 + (0.0 if 0.0 > a0 else a0) ** 2 / (2.0 * tab.j_lin[k0])
    A, _ = piece_room(tab, k0, w, 0.0)
    aa = abs(a0)
    _, J = piece_room(tab, k0, w, aa if aa > A else A)
    shrink = 1.0 - LIMIT_MARGIN
    A *= shrink
    J *= shrink
    best: ScalarProfile | None = None
    best_aj = (0.0, 0.0)
    for it in range(8):
        prof, A2, J2 = _check_candidate(path, tab, s, v0, a0, A, J)
        if prof is not None:
            best, best_aj = prof, (A, J)
            break
        if A2 <= 0.0 or J2 <= 0.0:
            break
        shrink = 1.0 - 0.01 * (it + 1) - LIMIT_MARGIN
        A = min(A, A2) * shrink
        J = min(J, J2) * shrink
    if hint is not None:
        A_h, J_h = float(hint[0]), float(hint[1])
        if best is None or A_h > best_aj[0] or J_h > best_aj[1]:
            prof, _, _ = _check_candidate(path, tab, s, v0, a0, A_h, J_h)
            if prof is not None and (best is None or prof.duration < best.duration):
                best, best_aj = prof, (A_h, J_h)
    if best is None:
        raise RobotModelError(
            f"no path-consistent stop within the joint limits from s = {s:.6g} rad, "
            f"sd = {v0:.6g} rad/s, sdd = {a0:.6g} rad/s^2 (path length {S:.6g} rad)"
        )
    return StopProfile(path, best, *best_aj)


def straight_line_stop_duration(
    sd: float, sdd: float, dq_ds: np.ndarray, limits: JointLimits
) -> float:
    """Duration of the time-optimal jerk-limited stop from path state ``(s', s'')`` along a
    straight line with direction ``dq_ds`` (path limits ``min_j a_j / |u_j|`` and
    ``min_j j_j / |u_j|``, exact on a straight line)."""
    lim = limit_arrays(limits, len(dq_ds))
    u = np.abs(np.asarray(dq_ds, dtype=float))
    with np.errstate(divide="ignore"):
        A = float(np.min(np.where(u > 0, lim.a / np.where(u > 0, u, 1.0), np.inf)))
        J = float(np.min(np.where(u > 0, lim.j / np.where(u > 0, u, 1.0), np.inf)))
    durs, _ = velocity_phases(max(sd, 0.0), sdd, 0.0, A, J)
    return float(sum(durs))


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
