"""Reference of the path-consistent stop (``sara_app.robot.failsafe``'s module docstring gives the
mathematics): plain Python, the oracle of the compiled planner
(:mod:`sara_app.robot.planning_kernels`) in ``tests/planning_reference.py`` and
``tests/test_failsafe.py``. Production never runs it.
"""

from __future__ import annotations

import math
from bisect import bisect_right

import numpy as np

from sara_app.errors import RobotModelError
from sara_app.robot.failsafe import StopProfile, _finite, rest_stop
from sara_app.robot.joints import LIMIT_MARGIN, REST_A, REST_V, S_TOL, limit_arrays
from sara_app.robot.model import JointLimits
from sara_app.robot.path import PathTrajectory
from sara_app.robot.path_limits import PathTables, path_tables, piece_room, sub_piece_room
from sara_app.robot.profile import ScalarProfile, velocity_phases


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
