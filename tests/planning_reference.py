"""An independent Python reference of a path follower's step planning: what
:func:`~sara_app.robot.planning_kernels.peek_kernel` computes (``PathFollower.peek``), written
with the profile's and the path's Python functions, in the same formulas and operation order, so
that the two are equal bit for bit (``tests/test_planning_kernels.py``). It reads the follower's
state and tables; the library runs only the compiled kernel."""

from __future__ import annotations

import math
from bisect import bisect_right

import numpy as np
from profile_reference import (
    cut_phases,
    phase_maxima,
    phases_at,
    phases_end,
    velocity_phases,
)
from stop_reference import plan_stop_unchecked

from sara_app.errors import RobotModelError
from sara_app.robot.joints import REST_A, REST_V, S_TOL
from sara_app.robot.profile import ScalarProfile
from sara_app.robot.trajectory import FollowerStep, PathFollower


def brake_gap(
    f: PathFollower,
    base: tuple[list[float], list[float]],
    tau: float,
    target: float,
    A: float,
    J: float,
) -> float:
    """Where a brake to ``target`` started at ``tau`` on ``base`` ends, in s."""
    s, v, a = phases_at(f._s, f._v, f._a, base[0], base[1], tau)
    d, j = velocity_phases(v, a, target, A, J)
    return phases_end(s, v, a, d, j)[0]


def fit_brake(
    f: PathFollower,
    base: tuple[list[float], list[float]],
    dt: float,
    target: float,
    pos: float,
    A: float,
    J: float,
) -> tuple[float, tuple[list[float], list[float]]]:
    """Latest start ``tau`` in ``[0, dt]`` of a brake to ``target`` that ends by ``pos``."""
    lo, hi = 0.0, dt
    if brake_gap(f, base, 0.0, target, A, J) >= pos:
        tau = 0.0
    else:
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            if brake_gap(f, base, mid, target, A, J) < pos:
                lo = mid
            else:
                hi = mid
            if hi - lo <= 1e-12 * dt:
                break
        tau = lo
    s, v, a = phases_at(f._s, f._v, f._a, base[0], base[1], tau)
    d, j = velocity_phases(v, a, target, A, J)
    bd, bj = cut_phases(base[0], base[1], tau) if tau > 0 else ([], [])
    return tau, (bd + d, bj + j)


def intended(f: PathFollower, dt: float) -> tuple[list[float], list[float], float, float]:
    """Phases of the intended motion from the current state, and the path limits used."""
    # (min and max spelt "b if b < a else a" and "b if b > a else a": the same values,
    # NaN included, without the calls; bisect_right(starts, x) - 1 is path.piece_index)
    s, v, a = f._s, f._v, f._a
    S = f._S
    A_box, J_box, V_box = f._A, f._J, f._V
    starts = f._starts
    k0 = bisect_right(starts, s) - 1
    k0 = 0 if k0 < 0 else k0
    # look-ahead: any stop from here with the smallest box of the path, and a shorter
    # window in which an acceleration must already fit the box (time to ramp it down)
    if v > 0 or a != 0:
        d, j = velocity_phases(v, a, 0.0, f._A_min, f._J_min)
        reach = phases_end(0.0, v, a, d, j)[0] if d else 0.0
        reach = 0.0 if 0.0 > reach else reach
    else:
        reach = 0.0
    ramp = (abs(v) + abs(a) * dt) * (f._ramp_c + 2.0 * dt)
    x = s + ramp + S_TOL
    kr = bisect_right(starts, S if S < x else x) - 1
    x = s + reach + ramp + S_TOL
    kw = bisect_right(starts, S if S < x else x) - 1
    kr = 0 if kr < 0 else kr
    kw = 0 if kw < 0 else kw
    if kr == k0:
        A_f, J_f = A_box[k0], J_box[k0]
    else:
        A_f, J_f = min(A_box[k0 : kr + 1]), min(J_box[k0 : kr + 1])
    cap = f._cap
    x = V_box[k0]
    base = velocity_phases(v, a, cap if cap < x else x, A_f, J_f)
    s1, v1, a1 = phases_at(s, v, a, base[0], base[1], dt)
    # constraints ahead: reach the admissible speed of every slower piece by its start,
    # braking within the boxes of the pieces up to it; standstill at the end of the path
    cons: list[tuple[float, float, float, float]] = []
    if kw > k0:
        A_run, J_run = A_f, J_f
        a1_sq = (0.0 if 0.0 > a1 else a1) ** 2
        for k in range(k0 + 1, kw + 1):
            x = A_box[k]
            A_run = x if x < A_run else A_run
            x = J_box[k]
            J_run = x if x < J_run else J_run
            x = V_box[k]
            V_k = cap if cap < x else x
            if V_k < v1 + a1_sq / (2.0 * J_run):
                cons.append((starts[k], V_k, A_run, J_run))
    if S - s <= reach + ramp + S_TOL:
        cons.append((S, 0.0, min(A_f, f._A_tail[k0]), min(J_f, f._J_tail[k0])))
    # of the brakes needed now, the one that slows down most within this step satisfies
    # the others too (they brake later or less)
    best: tuple[tuple[float, float], tuple[list[float], list[float]], float, float] | None
    best = None
    for pos, target, A_c, J_c in cons:
        dd, jj = velocity_phases(v1, a1, target, A_c, J_c)
        if phases_end(s1, v1, a1, dd, jj)[0] >= pos - S_TOL * 1e-3:
            _, plan = fit_brake(f, base, dt, target, pos, A_c, J_c)
            _, v_end, a_end = phases_at(s, v, a, plan[0], plan[1], dt)
            if best is None or (v_end, a_end) < best[0]:
                best = ((v_end, a_end), plan, A_c, J_c)
    if best is not None:
        return best[1][0], best[1][1], best[2], best[3]
    return base[0], base[1], A_f, J_f


def step_ok(f: PathFollower, prof: ScalarProfile, s1: float) -> bool:
    """Joint limits hold over the step (rigorous: piece maxima and profile maxima, taken
    per piece over the part of the step spent in it)."""
    s0, v0, a0 = prof.start
    starts = f._starts
    k0 = bisect_right(starts, s0) - 1  # path.piece_index
    k1 = bisect_right(starts, s1) - 1
    k0 = 0 if k0 < 0 else k0
    k1 = 0 if k1 < 0 else k1
    if k1 == k0:
        vmax, amax, jmax = phase_maxima(v0, a0, prof.durs, prof.jerks)
        if vmax <= f._V[k0] and amax <= f._A[k0] and jmax <= f._J[k0]:
            return True  # _piece_ok's first test
        return piece_ok(f, k0, vmax, amax, jmax)
    T = prof.duration
    t_in = 0.0
    for k in range(k0, k1 + 1):
        if k < k1:  # leaves piece k inside the step: bracket the crossing time
            b = f.path._s0_list[k + 1]
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
        durs, jerks = cut_phases(part.durs, part.jerks, max(t_out - t_in, 0.0))
        sv = part.start
        if not piece_ok(f, k, *phase_maxima(sv[1], sv[2], durs, jerks)):
            return False
        t_in = t_next
    return True


def piece_ok(f: PathFollower, k: int, vmax: float, amax: float, jmax: float) -> bool:
    """Joint limits hold on piece ``k`` at path speed, acceleration, jerk up to these."""
    if vmax <= f._V[k] and amax <= f._A[k] and jmax <= f._J[k]:
        return True
    p = f.path
    lim = f._lim
    M1, M2, M3 = p.M1[k], p.M2[k], p.M3[k]
    return bool(
        np.all(M1 * vmax <= lim.v)
        and np.all(M2 * vmax**2 + M1 * amax <= lim.a)
        and np.all(M3 * vmax**3 + 3 * M2 * vmax * amax + M1 * jmax <= lim.j)
    )


def reference_peek(f: PathFollower, dt: float) -> FollowerStep:
    """``f.peek(dt)`` planned in Python (the follower is not changed)."""
    dt = float(dt)
    s, v, a = f._s, f._v, f._a
    S = f._S
    path = f.path
    if (S - s <= S_TOL and v <= REST_V and abs(a) <= REST_A) or f._n_pieces == 0:
        prof = ScalarProfile(s, 0.0, 0.0, [dt], [0.0])  # done (at rest at the end)
        return FollowerStep(dt, path, prof, (s, 0.0, 0.0), f._stop, False)
    durs, jerks, A_f, J_f = intended(f, dt)
    d, j = cut_phases(durs, jerks, dt)
    prof = ScalarProfile(s, v, a, d, j)
    s1, v1, a1 = prof.end
    if abs(v1) <= 1e-12 and abs(a1) <= 1e-9:
        v1, a1 = (0.0 if 0.0 > v1 else v1), 0.0
    if S - s1 <= S_TOL and v1 <= REST_V:
        s1 = S if S < s1 else s1
    if v1 >= 0.0 and s1 <= S + S_TOL and step_ok(f, prof, s1):
        if math.isfinite(s1) and math.isfinite(v1) and math.isfinite(a1):
            try:
                stop = plan_stop_unchecked(path, f._tab, s1, v1, a1, (A_f, J_f))
            except RobotModelError:
                stop = None
            if stop is not None:
                return FollowerStep(dt, path, prof, (s1, v1, a1), stop, False)
    # fallback: the failsafe already held
    held = f._stop
    d, j = cut_phases(held.profile.durs, held.profile.jerks, dt)
    prof = ScalarProfile(s, v, a, d, j)
    return FollowerStep(dt, path, prof, prof.end, held.advanced(dt), True)
