"""The scalar phase functions of sara_app.robot.profile in plain Python: the reference of the
planner's compiled ones (sara_app.robot.planning_kernels), which the library runs (tests compare
them bit for bit), and the phase arithmetic of tests/planning_reference.py."""

from __future__ import annotations

import math


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
    # phases of positive duration only, jerks signed by d (a zero jerk keeps the sign of d)
    if ap > A:
        t1 = (ap - A) / J
        hold = (dv_total - ap * ap / two_j) / A
        return _three(t1, hold, A / J, -J, -J, d)
    p2 = J * dv_total + 0.5 * ap * ap
    p = math.sqrt(0.0 if 0.0 > p2 else p2)  # max(p2, 0.0), NaN kept
    if p <= A:
        t1 = (p - ap) / J
        t2 = p / J
        if t1 > 0.0:
            if t2 > 0.0:
                return [t1, t2], [d * J, d * -J]
            return [t1], [d * J]
        if t2 > 0.0:
            return [t2], [d * -J]
        return [], []
    hold = (dv_total - (2.0 * A * A - ap * ap) / two_j) / A
    return _three((A - ap) / J, hold, A / J, J, -J, d)


def _three(
    t1: float, hold: float, t3: float, j1: float, j3: float, d: float
) -> tuple[list[float], list[float]]:
    """Phases ``(t1, j1), (hold, 0), (t3, j3)`` of positive duration, jerks times ``d``."""
    durs: list[float] = []
    jerks: list[float] = []
    if t1 > 0.0:
        durs.append(t1)
        jerks.append(d * j1)
    if hold > 0.0:  # max(hold, 0.0) > 0.0
        durs.append(hold)
        jerks.append(d * 0.0)
    if t3 > 0.0:
        durs.append(t3)
        jerks.append(d * j3)
    return durs, jerks


def phases_end(
    s: float, v: float, a: float, durs: list[float], jerks: list[float]
) -> tuple[float, float, float]:
    """State ``(s, v, a)`` at the end of the phases."""
    for t, j in zip(durs, jerks):
        s += t * (v + t * (0.5 * a + t * j / 6.0))
        v += t * (a + 0.5 * t * j)
        a += t * j
    return s, v, a


def phases_at(
    s: float, v: float, a: float, durs: list[float], jerks: list[float], t: float
) -> tuple[float, float, float]:
    """State at time ``t`` (after the last phase the motion goes on with zero jerk)."""
    for T, j in zip(durs, jerks):
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
    for T, j in zip(durs, jerks):  # "if x > m: m = x" is max(m, x), NaN handling included
        if j != 0.0:
            tau = -a / j
            if 0.0 < tau < T:
                x = v + tau * (a + 0.5 * tau * j)
                if x > vmax:
                    vmax = x
            x = abs(j)
            if x > jmax:
                jmax = x
        v += T * (a + 0.5 * T * j)
        a += T * j
        if v > vmax:
            vmax = v
        x = abs(a)
        if x > amax:
            amax = x
    return vmax, amax, jmax


def cut_phases(durs: list[float], jerks: list[float], t: float) -> tuple[list[float], list[float]]:
    """The phases over ``[0, t]``, padded with a zero-jerk phase if they end earlier."""
    out_d: list[float] = []
    out_j: list[float] = []
    rest = t
    for T, j in zip(durs, jerks):
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
