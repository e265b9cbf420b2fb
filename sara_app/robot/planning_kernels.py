"""Compiled (numba) planning of one path-follower step: the intended motion with its brakes
before slower pieces and the path's end, the joint-limit check of the step and the failsafe stop
from its end (``plan_stop_unchecked`` of ``tests/stop_reference.py`` with its candidate checks,
entry bounds and piece room), in one call from :meth:`PathFollower.peek
<sara_app.robot.trajectory.PathFollower.peek>`: the only planning the library runs.

``tests/planning_reference.py`` is its reference in Python, in the same formulas and operation
order (``tests/test_planning_kernels.py`` checks the two equal bit for bit on random paths and
states). Python's ``min``/``max`` are spelt as the comparisons they make (the same NaN handling)
and ``x ** 2`` / ``x ** 3`` of a Python float as ``math.pow`` with the exponent read at run time
from ``consts`` (with a literal exponent LLVM would turn ``pow(x, 2.0)`` into ``x * x``, which
differs from the C library's ``pow`` in the last bit for some ``x``).

Phase lists of at most three phases (a time-optimal velocity change) are tuples
``(count, d0, d1, d2, j0, j1, j2)`` (scalar arguments: no reference counting in the calls);
longer ones (the step) are arrays with a count. Explicit signatures and ``cache=True``:
compiled or loaded from the cache at import, never in a control loop; helpers are called only
within this file and constants from other modules are passed as arguments (numba's cache does
not notice changes in other files).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, types

from sara_app.kernel_types import B1 as _b1
from sara_app.kernel_types import F8 as _f8
from sara_app.kernel_types import IP as _ip
from sara_app.kernel_types import RO1 as _RO1
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import RO3 as _RO3
from sara_app.kernel_types import W1 as _W1

__all__ = [
    "CONSTS",
    "OUT_LEN",
    "PC_COLS",
    "cut_phases_kernel",
    "peek_kernel",
    "phase_maxima_kernel",
    "phases_at_kernel",
    "phases_end_kernel",
    "profile_record",
    "velocity_phases_kernel",
]

# columns of the per-piece table ``pc (P, PC_COLS)``
S0, V, A, J, A_TAIL, J_TAIL, LIN, V_LIN, A_LIN, J_LIN, X0, X1, INV_L = range(13)
PC_COLS = 13
# ``consts``: S_TOL, REST_V, REST_A, LIMIT_MARGIN (sara_app.robot.joints) and the exponents 2, 3
C_STOL, C_REST_V, C_REST_A, C_MARGIN, C_TWO, C_THREE = range(6)
CONSTS = 6
# ``out``: the step's profile, the stop's profile (records of ``profile_record``), the step's
# end state and the stop's limits A, J
H_MAX = 16  # scratch phase lists
H_CAP, S_CAP = 8, 3  # phases of a step (a brake fitted in: at most 4 + 3, cut at dt: + 1), a stop
O_HEAD = 0
O_STOP = O_HEAD + 1 + 2 * H_CAP + 4 * (H_CAP + 1)
O_END = O_STOP + 1 + 2 * S_CAP + 4 * (S_CAP + 1)  # s1, s1', s1''
O_LIM = O_END + 3  # the stop's A, J
OUT_LEN = O_LIM + 2


def profile_record(o: list[float], off: int, cap: int) -> tuple[list[float], ...]:
    """``(durs, jerks, tb, sb, vb, ab)`` of the profile record at ``o[off:]`` (``out`` as a
    list; ``cap``: H_CAP or S_CAP): the count, ``cap`` durations, ``cap`` jerks, then
    ``cap + 1`` break times, positions, speeds, accelerations."""
    n = int(o[off])
    d = off + 1
    j = d + cap
    t = j + cap
    m = n + 1
    c = cap + 1
    return (
        o[d : d + n], o[j : j + n], o[t : t + m], o[t + c : t + c + m],
        o[t + 2 * c : t + 2 * c + m], o[t + 3 * c : t + 3 * c + m],
    )  # fmt: skip


@njit(cache=True)
def record_start(out: np.ndarray, off: int, cap: int) -> tuple[int, float, float, float]:
    """Phase count and start state ``(s, s', s'')`` of the profile record at ``out[off:]``
    (``out`` an array; the layout of :func:`profile_record`)."""
    n = int(out[off])
    t = off + 1 + 2 * cap
    c = cap + 1
    return n, out[t + c], out[t + 2 * c], out[t + 3 * c]


STEP, STEP_REST, FALLBACK = 0, 1, 2  # peek_kernel's status

_PH = types.UniTuple(_f8, 7)
_S2, _S3 = types.UniTuple(_f8, 2), types.UniTuple(_f8, 3)
_EMPTY = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


# -- scalar phase lists ------------------------------------------------------------------------


@njit(_PH(_PH, _f8, _f8), cache=True)
def _push(ph: tuple, t: float, j: float) -> tuple:
    """``ph`` with the phase ``(t, j)`` appended."""
    n = ph[0]
    if n == 0.0:
        return (1.0, t, ph[2], ph[3], j, ph[5], ph[6])
    if n == 1.0:
        return (2.0, ph[1], t, ph[3], ph[4], j, ph[6])
    return (3.0, ph[1], ph[2], t, ph[4], ph[5], j)


@njit(_PH(_f8, _f8, _f8, _f8, _f8, _f8), cache=True)
def _three(t1: float, hold: float, t3: float, j1: float, j3: float, d: float) -> tuple:
    """``profile._three``: phases ``(t1, j1), (hold, 0), (t3, j3)`` of positive duration."""
    ph = _EMPTY
    if t1 > 0.0:
        ph = _push(ph, t1, d * j1)
    if hold > 0.0:
        ph = _push(ph, hold, d * 0.0)
    if t3 > 0.0:
        ph = _push(ph, t3, d * j3)
    return ph


@njit(_PH(_f8, _f8, _f8, _f8, _f8), cache=True)
def velocity_phases_kernel(v0: float, a0: float, vt: float, A: float, J: float) -> tuple:
    """``profile.velocity_phases``."""
    two_j = 2.0 * J
    vr = v0 + a0 * abs(a0) / two_j
    dv = vt - vr
    if abs(dv) <= 1e-12 * (abs(v0) + abs(vt) + a0 * a0 / two_j) + 1e-15:
        if a0 == 0.0:
            return _EMPTY
        return (1.0, abs(a0) / J, 0.0, 0.0, -J if a0 > 0.0 else J, 0.0, 0.0)
    d = 1.0 if dv > 0.0 else -1.0
    ap = d * a0
    dv_total = d * (vt - v0)
    if ap > A:
        t1 = (ap - A) / J
        hold = (dv_total - ap * ap / two_j) / A
        return _three(t1, hold, A / J, -J, -J, d)
    p2 = J * dv_total + 0.5 * ap * ap
    p = math.sqrt(0.0 if 0.0 > p2 else p2)
    if p <= A:
        ph = _EMPTY
        t1 = (p - ap) / J
        t2 = p / J
        if t1 > 0.0:
            ph = _push(ph, t1, d * J)
        if t2 > 0.0:
            ph = _push(ph, t2, d * -J)
        return ph
    hold = (dv_total - (2.0 * A * A - ap * ap) / two_j) / A
    return _three((A - ap) / J, hold, A / J, J, -J, d)


@njit(_S3(_f8, _f8, _f8, _PH), cache=True)
def phases_end_kernel(s: float, v: float, a: float, ph: tuple) -> tuple:
    """``profile.phases_end``."""
    for i in range(int(ph[0])):
        t = ph[1 + i]
        j = ph[4 + i]
        s += t * (v + t * (0.5 * a + t * j / 6.0))
        v += t * (a + 0.5 * t * j)
        a += t * j
    return s, v, a


@njit(_S3(_f8, _f8, _f8, _PH, _f8), cache=True)
def _ph_at(s: float, v: float, a: float, ph: tuple, t: float) -> tuple:
    """``profile.phases_at``."""
    for i in range(int(ph[0])):
        T = ph[1 + i]
        j = ph[4 + i]
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


@njit(_f8(_PH), cache=True)
def _ph_duration(ph: tuple) -> float:
    """``ScalarProfile.duration`` of the phases."""
    t = 0.0
    for i in range(int(ph[0])):
        t += ph[1 + i]
    return t


# -- array phase lists (the step) ----------------------------------------------------------


@njit(_S3(_f8, _f8, _f8, _W1, _W1, _ip, _f8), cache=True)
def phases_at_kernel(
    s: float, v: float, a: float, durs: np.ndarray, jerks: np.ndarray, n: int, t: float
) -> tuple:
    """``profile.phases_at`` of the first ``n`` phases of ``durs``, ``jerks``."""
    for i in range(n):
        T = durs[i]
        j = jerks[i]
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


@njit(_S3(_f8, _f8, _W1, _W1, _ip), cache=True)
def phase_maxima_kernel(v: float, a: float, durs: np.ndarray, jerks: np.ndarray, n: int) -> tuple:
    """``profile.phase_maxima`` of the first ``n`` phases."""
    vmax, amax, jmax = v, abs(a), 0.0
    for i in range(n):
        T = durs[i]
        j = jerks[i]
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


@njit(_ip(_W1, _W1, _ip, _f8, _W1, _W1), cache=True)
def cut_phases_kernel(
    durs: np.ndarray, jerks: np.ndarray, n: int, t: float, od: np.ndarray, oj: np.ndarray
) -> int:
    """``profile.cut_phases`` of the first ``n`` phases into ``od``, ``oj``; their count."""
    m = 0
    rest = t
    for i in range(n):
        if rest <= 0.0:
            break
        T = durs[i]
        take = T if T < rest else rest
        od[m] = take
        oj[m] = jerks[i]
        m += 1
        rest -= take
    if rest > 0.0:
        od[m] = rest
        oj[m] = 0.0
        m += 1
    return m


# -- path pieces -------------------------------------------------------------------------------


@njit(_ip(_RO2, _f8), cache=True)
def _piece(pc: np.ndarray, x: float) -> int:
    """``path.piece_index``: ``max(bisect_right(starts, x) - 1, 0)`` (NaN: the last piece)."""
    lo, hi = 0, pc.shape[0]
    while lo < hi:
        mid = (lo + hi) // 2
        if x < pc[mid, S0]:
            hi = mid
        else:
            lo = mid + 1
    return lo - 1 if lo > 0 else 0


@njit(_S2(_ip, _f8, _f8, _RO2, _RO3), cache=True)
def _piece_room(k: int, w: float, am: float, pc: np.ndarray, rows: np.ndarray) -> tuple:
    """``path_limits.piece_room``; ``rows (P, n, 7)``: per joint ``M1, M2, M3, 1/M1, v, a, j``."""
    if pc[k, LIN] != 0.0:
        if w > pc[k, V_LIN]:
            return -1.0, -1.0
        return pc[k, A_LIN], pc[k, J_LIN]
    w2 = w * w
    w3 = w2 * w
    A_ = math.inf
    J_ = math.inf
    for c in range(rows.shape[1]):
        m1 = rows[k, c, 0]
        m2 = rows[k, c, 1]
        im1 = rows[k, c, 3]
        if m1 * w > rows[k, c, 4]:
            return -1.0, -1.0
        ar = (rows[k, c, 5] - m2 * w2) * im1
        jr = (rows[k, c, 6] - rows[k, c, 2] * w3 - 3.0 * m2 * w * am) * im1
        if ar < A_:
            A_ = ar
        if jr < J_:
            J_ = jr
    return A_, J_


@njit(_S2(_ip, _f8, _f8, _f8, _f8, _RO2, _RO3, _RO3), cache=True)
def _sub_piece_room(
    k: int,
    sa: float,
    sb: float,
    w: float,
    am: float,
    pc: np.ndarray,
    rows: np.ndarray,
    geo: np.ndarray,
) -> tuple:
    """``path_limits.sub_piece_room``; ``geo (P, 2, n)``: per piece ``u`` and ``dl``."""
    if pc[k, LIN] != 0.0:
        return _piece_room(k, w, am, pc, rows)
    s0 = pc[k, S0]
    x_lo, x_hi = pc[k, X0], pc[k, X1]
    iL = pc[k, INV_L]
    x = x_lo + (sa - s0) * iL
    x = x_lo if x_lo > x else x
    xa = x_hi if x_hi < x else x
    x = x_lo + (sb - s0) * iL
    x = xa if xa > x else x
    xb = x_hi if x_hi < x else x
    ha, hb = xa * xa * (3.0 - 2.0 * xa), xb * xb * (3.0 - 2.0 * xb)
    x = xa if xa > 0.5 else 0.5
    xm = xb if xb < x else x
    dh = 6.0 * xm * (1.0 - xm) * iL
    p, q = abs(6.0 - 12.0 * xa), abs(6.0 - 12.0 * xb)
    ddh = (q if q > p else p) * iL * iL
    w2 = w * w
    w3 = w2 * w
    A_ = math.inf
    J_ = math.inf
    for c in range(rows.shape[1]):
        uj = geo[k, 0, c]
        dj = geo[k, 1, c]
        p, q = abs(uj + ha * dj), abs(uj + hb * dj)
        m1 = q if q > p else p
        adj = abs(dj)
        m2 = adj * dh
        if m1 * w > rows[k, c, 4]:
            return -1.0, -1.0
        if m1 > 0.0:
            ar = (rows[k, c, 5] - m2 * w2) / m1
            jr = (rows[k, c, 6] - adj * ddh * w3 - 3.0 * m2 * w * am) / m1
            if ar < A_:
                A_ = ar
            if jr < J_:
                J_ = jr
    return A_, J_


@njit(_b1(_ip, _f8, _f8, _f8, _RO2, _RO3, _RO1), cache=True)
def _piece_ok(
    k: int,
    vmax: float,
    amax: float,
    jmax: float,
    pc: np.ndarray,
    rows: np.ndarray,
    consts: np.ndarray,
) -> bool:
    """``PathFollower._piece_ok`` (the per-joint test as numpy evaluates it, element by
    element)."""
    if vmax <= pc[k, V] and amax <= pc[k, A] and jmax <= pc[k, J]:
        return True
    n = rows.shape[1]
    for c in range(n):
        if not rows[k, c, 0] * vmax <= rows[k, c, 4]:
            return False
    v2 = math.pow(vmax, consts[C_TWO])
    for c in range(n):
        if not rows[k, c, 1] * v2 + rows[k, c, 0] * amax <= rows[k, c, 5]:
            return False
    v3 = math.pow(vmax, consts[C_THREE])
    for c in range(n):
        m1, m2, m3 = rows[k, c, 0], rows[k, c, 1], rows[k, c, 2]
        if not m3 * v3 + 3.0 * m2 * vmax * amax + m1 * jmax <= rows[k, c, 6]:
            return False
    return True


# -- the failsafe stop -------------------------------------------------------------------------


@njit(_S2(_f8, _f8, _f8, _PH, _f8, _f8, _f8), cache=True)
def _entry_bounds(
    s: float, v: float, a: float, ph: tuple, b: float, t_pk: float, vp: float
) -> tuple:
    """``stop_reference._entry_bounds`` (tests) of the stop ``ph`` from ``(s, v, a)``."""
    a_start = a
    t0 = 0.0
    j = 0.0
    reached = False
    for i in range(int(ph[0])):
        T = ph[1 + i]
        j = ph[4 + i]
        s1 = s + T * (v + T * (0.5 * a + T * j / 6.0))
        if s1 >= b:
            reached = True
            break
        s, v, a = s1, v + T * (a + 0.5 * T * j), a + T * j
        t0 += T
    if not reached:
        return 0.0, 0.0
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
        if over > 0.0:
            fp = v + tau * (a + 0.5 * tau * j)
            if fp > 0.0:
                x = tau - 2.0 * over / fp - 1e-15
                tau = 0.0 if 0.0 > x else x
            else:
                tau = 0.0
            if s + tau * (v + tau * (0.5 * a + tau * j / 6.0)) > b:
                tau = 0.0
    t_in = t0 + tau
    w = vp if t_in < t_pk else v + tau * (a + 0.5 * tau * j)
    am = abs(a + tau * j)
    tb = 0.0
    ab = a_start
    for i in range(int(ph[0])):  # the profile's breaks after the start
        T = ph[1 + i]
        ab += T * ph[4 + i]
        tb += T
        if tb >= t_in and abs(ab) > am:
            am = abs(ab)
    return w, am


_CAND = types.Tuple((_b1, _f8, _f8, _PH))


@njit(_CAND(_f8, _f8, _f8, _f8, _f8, _f8, _RO2, _RO3, _RO3, _RO1), cache=True)
def _check_candidate(
    s: float,
    v0: float,
    a0: float,
    A_: float,
    J_: float,
    S: float,
    pc: np.ndarray,
    rows: np.ndarray,
    geo: np.ndarray,
    consts: np.ndarray,
) -> tuple:
    """``stop_reference._check_candidate`` (tests): ``(valid, A2, J2, phases)``."""
    if A_ <= 0.0 or J_ <= 0.0:
        return False, -1.0, -1.0, _EMPTY
    if a0 < 0.0 and v0 < a0 * a0 / (2.0 * J_) * (1.0 - 1e-9) - 1e-15:
        return False, -1.0, -1.0, _EMPTY
    ph = velocity_phases_kernel(v0, a0, 0.0, A_, J_)
    s_end = phases_end_kernel(s, v0, a0, ph)[0]
    if s_end > S + consts[C_STOL]:
        return False, -1.0, -1.0, ph
    if a0 > 0.0:
        t_pk = a0 / J_
        vp = v0 + a0 * a0 / (2.0 * J_)
    else:
        t_pk, vp = 0.0, v0
    amax0 = abs(a0)
    ab = a0
    for i in range(int(ph[0])):
        ab += ph[1 + i] * ph[4 + i]
        x = abs(ab)
        if x > amax0:
            amax0 = x
    k0 = _piece(pc, s)
    k1 = _piece(pc, S if S < s_end else s_end)
    ok = True
    A2 = math.inf
    J2 = math.inf
    for k in range(k0, k1 + 1):
        if k == k0:
            w, am = vp, amax0
        else:
            w, am = _entry_bounds(s, v0, a0, ph, pc[k, S0], t_pk, vp)
        if k == k0 or k == k1:
            sa = s if k == k0 else pc[k, S0]
            sb = s_end if k == k1 else pc[k + 1, S0]
            Ak, Jk = _sub_piece_room(k, sa, sb, w, am, pc, rows, geo)
        else:
            Ak, Jk = _piece_room(k, w, am, pc, rows)
        if Ak < 0.0 and Jk < 0.0:
            return False, -1.0, -1.0, ph
        if am > Ak:
            ok = False
        if Ak < A2:
            A2 = Ak
        if Jk < J2:
            J2 = Jk
    ok = ok and J_ <= J2
    return ok, A2, J2, ph


_STOP = types.Tuple((_ip, _PH, _f8, _f8, _f8, _f8))


@njit(_STOP(_f8, _f8, _f8, _f8, _f8, _f8, _RO2, _RO3, _RO3, _RO1), cache=True)
def _plan_stop(
    s: float,
    v0: float,
    a0: float,
    A_h: float,
    J_h: float,
    S: float,
    pc: np.ndarray,
    rows: np.ndarray,
    geo: np.ndarray,
    consts: np.ndarray,
) -> tuple:
    """``stop_reference.plan_stop_unchecked`` (tests) with the hint ``(A_h, J_h)``: ``(status,
    phases, A, J, s, s')`` with status STEP (a stop), STEP_REST (already at rest: ``rest_stop`` at
    ``s``) or FALLBACK (no stop: the reference raises)."""
    s_tol = consts[C_STOL]
    if s < -s_tol or s > S + s_tol:
        return FALLBACK, _EMPTY, 0.0, 0.0, s, v0
    if v0 < -1e-12:
        return FALLBACK, _EMPTY, 0.0, 0.0, s, v0
    s = 0.0 if 0.0 > s else s
    s = S if S < s else s
    v0 = 0.0 if 0.0 > v0 else v0
    if v0 <= consts[C_REST_V] and abs(a0) <= consts[C_REST_A]:
        return STEP_REST, _EMPTY, 0.0, 0.0, s, v0
    if pc.shape[0] == 0:
        return FALLBACK, _EMPTY, 0.0, 0.0, s, v0
    k0 = _piece(pc, s)
    w = v0 + math.pow(0.0 if 0.0 > a0 else a0, consts[C_TWO]) / (2.0 * pc[k0, J_LIN])
    A_ = _piece_room(k0, w, 0.0, pc, rows)[0]
    aa = abs(a0)
    J_ = _piece_room(k0, w, aa if aa > A_ else A_, pc, rows)[1]
    margin = consts[C_MARGIN]
    shrink = 1.0 - margin
    A_ *= shrink
    J_ *= shrink
    found = False
    best = _EMPTY
    bA = 0.0
    bJ = 0.0
    for it in range(8):
        ok, A2, J2, ph = _check_candidate(s, v0, a0, A_, J_, S, pc, rows, geo, consts)
        if ok:
            found, best, bA, bJ = True, ph, A_, J_
            break
        if A2 <= 0.0 or J2 <= 0.0:
            break
        shrink = 1.0 - 0.01 * (it + 1) - margin
        A_ = (A2 if A2 < A_ else A_) * shrink
        J_ = (J2 if J2 < J_ else J_) * shrink
    if not found or A_h > bA or J_h > bJ:
        ok, _, _, ph = _check_candidate(s, v0, a0, A_h, J_h, S, pc, rows, geo, consts)
        if ok and (not found or _ph_duration(ph) < _ph_duration(best)):
            found, best, bA, bJ = True, ph, A_h, J_h
    if not found:
        return FALLBACK, _EMPTY, 0.0, 0.0, s, v0
    return STEP, best, bA, bJ, s, v0


# -- the intended motion -----------------------------------------------------------------------


@njit(_f8(_f8, _f8, _f8, _PH, _f8, _f8, _f8, _f8), cache=True)
def _brake_gap(
    s: float, v: float, a: float, base: tuple, tau: float, target: float, A_: float, J_: float
) -> float:
    """``PathFollower._brake_gap`` from the state ``(s, v, a)``."""
    s, v, a = _ph_at(s, v, a, base, tau)
    return phases_end_kernel(s, v, a, velocity_phases_kernel(v, a, target, A_, J_))[0]


@njit(_ip(_f8, _f8, _f8, _PH, _f8, _f8, _f8, _f8, _f8, _W1, _W1), cache=True)
def _fit_brake(
    s: float,
    v: float,
    a: float,
    base: tuple,
    dt: float,
    target: float,
    pos: float,
    A_: float,
    J_: float,
    pd: np.ndarray,
    pj: np.ndarray,
) -> int:
    """``PathFollower._fit_brake``: its plan into ``pd``, ``pj``; the phase count."""
    lo, hi = 0.0, dt
    if _brake_gap(s, v, a, base, 0.0, target, A_, J_) >= pos:
        tau = 0.0
    else:
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            if _brake_gap(s, v, a, base, mid, target, A_, J_) < pos:
                lo = mid
            else:
                hi = mid
            if hi - lo <= 1e-12 * dt:
                break
        tau = lo
    s2, v2, a2 = _ph_at(s, v, a, base, tau)
    d = velocity_phases_kernel(v2, a2, target, A_, J_)
    n = 0
    if tau > 0.0:  # cut_phases(base, tau)
        rest = tau
        for i in range(int(base[0])):
            if rest <= 0.0:
                break
            T = base[1 + i]
            take = T if T < rest else rest
            pd[n] = take
            pj[n] = base[4 + i]
            n += 1
            rest -= take
        if rest > 0.0:
            pd[n] = rest
            pj[n] = 0.0
            n += 1
    for i in range(int(d[0])):
        pd[n] = d[1 + i]
        pj[n] = d[4 + i]
        n += 1
    return n


_INTENDED = types.Tuple((_ip, _f8, _f8))


@njit(
    _INTENDED(_f8, _f8, _f8, _f8, _f8, _f8, _f8, _f8, _f8, _RO2, _RO1, _W1, _W1, _W1, _W1),
    cache=True,
)
def _intended(
    s: float,
    v: float,
    a: float,
    dt: float,
    cap: float,
    S: float,
    A_min: float,
    J_min: float,
    ramp_c: float,
    pc: np.ndarray,
    consts: np.ndarray,
    pd: np.ndarray,
    pj: np.ndarray,
    td: np.ndarray,
    tj: np.ndarray,
) -> tuple:
    """``PathFollower._intended``: its phases into ``pd``, ``pj`` (``td``, ``tj``: scratch);
    ``(count, A, J)``."""
    s_tol = consts[C_STOL]
    k0 = _piece(pc, s)
    if v > 0 or a != 0:
        ph = velocity_phases_kernel(v, a, 0.0, A_min, J_min)
        reach = phases_end_kernel(0.0, v, a, ph)[0] if ph[0] > 0.0 else 0.0
        reach = 0.0 if 0.0 > reach else reach
    else:
        reach = 0.0
    ramp = (abs(v) + abs(a) * dt) * (ramp_c + 2.0 * dt)
    x = s + ramp + s_tol
    kr = _piece(pc, S if S < x else x)
    x = s + reach + ramp + s_tol
    kw = _piece(pc, S if S < x else x)
    A_f, J_f = pc[k0, A], pc[k0, J]
    for k in range(k0 + 1, kr + 1):  # min over the pieces k0..kr
        x = pc[k, A]
        A_f = x if x < A_f else A_f
        x = pc[k, J]
        J_f = x if x < J_f else J_f
    x = pc[k0, V]
    base = velocity_phases_kernel(v, a, cap if cap < x else x, A_f, J_f)
    s1, v1, a1 = _ph_at(s, v, a, base, dt)
    # the constraints ahead, each tried in the order the Python method lists them
    found = False
    bv = 0.0
    ba = 0.0
    bA = 0.0
    bJ = 0.0
    n_best = 0
    A_run, J_run = A_f, J_f
    a1_sq = math.pow(0.0 if 0.0 > a1 else a1, consts[C_TWO]) if kw > k0 else 0.0
    for k in range(k0 + 1, kw + 2):
        if k <= kw:
            x = pc[k, A]
            A_run = x if x < A_run else A_run
            x = pc[k, J]
            J_run = x if x < J_run else J_run
            x = pc[k, V]
            V_k = cap if cap < x else x
            if not V_k < v1 + a1_sq / (2.0 * J_run):
                continue
            pos, target, A_c, J_c = pc[k, S0], V_k, A_run, J_run
        else:  # standstill at the end of the path
            if not S - s <= reach + ramp + s_tol:
                continue
            x = pc[k0, A_TAIL]
            A_c = x if x < A_f else A_f
            x = pc[k0, J_TAIL]
            J_c = x if x < J_f else J_f
            pos, target = S, 0.0
        ph = velocity_phases_kernel(v1, a1, target, A_c, J_c)
        if phases_end_kernel(s1, v1, a1, ph)[0] >= pos - s_tol * 1e-3:
            n = _fit_brake(s, v, a, base, dt, target, pos, A_c, J_c, td, tj)
            _, v_end, a_end = phases_at_kernel(s, v, a, td, tj, n, dt)
            if found:
                better = v_end < bv if v_end != bv else a_end < ba  # (v, a) < (bv, ba)
            else:
                better = True
            if better:
                found, bv, ba, bA, bJ = True, v_end, a_end, A_c, J_c
                n_best = n
                for i in range(n):
                    pd[i] = td[i]
                    pj[i] = tj[i]
    if found:
        return n_best, bA, bJ
    n = int(base[0])
    for i in range(n):
        pd[i] = base[1 + i]
        pj[i] = base[4 + i]
    return n, A_f, J_f


# -- the step's joint limits -------------------------------------------------------------------


@njit(_b1(_f8, _f8, _f8, _W1, _W1, _ip, _f8, _RO2, _RO3, _RO1, _W1, _W1, _W1, _W1), cache=True)
def _step_ok(
    s0: float,
    v0: float,
    a0: float,
    hd: np.ndarray,
    hj: np.ndarray,
    n: int,
    s1: float,
    pc: np.ndarray,
    rows: np.ndarray,
    consts: np.ndarray,
    td: np.ndarray,
    tj: np.ndarray,
    cd: np.ndarray,
    cj: np.ndarray,
) -> bool:
    """``PathFollower._step_ok`` of the step ``hd, hj`` (``n`` phases) from ``(s0, v0, a0)``
    (``td``, ``tj``, ``cd``, ``cj``: scratch)."""
    k0 = _piece(pc, s0)
    k1 = _piece(pc, s1)
    if k1 == k0:
        vmax, amax, jmax = phase_maxima_kernel(v0, a0, hd, hj, n)
        return _piece_ok(k0, vmax, amax, jmax, pc, rows, consts)
    T = 0.0
    for i in range(n):
        T += hd[i]
    t_in = 0.0
    for k in range(k0, k1 + 1):
        if k < k1:  # bracket the time the step leaves piece k (prof.state_at)
            b = pc[k + 1, S0]
            lo, hi = t_in, T
            for _ in range(60):
                mid = 0.5 * (lo + hi)
                if phases_at_kernel(s0, v0, a0, hd, hj, n, mid)[0] < b:
                    lo = mid
                else:
                    hi = mid
                if hi - lo <= 1e-15:
                    break
            t_out, t_next = hi, lo
        else:
            t_out, t_next = T, T
        # prof.tail(t_in): its start state and phases
        _, pv, pa = phases_at_kernel(s0, v0, a0, hd, hj, n, t_in)
        m = 0
        acc = 0.0
        for i in range(n):
            start = acc
            acc = acc + hd[i]
            if acc > t_in:
                td[m] = acc - (t_in if t_in > start else start)
                tj[m] = hj[i]
                m += 1
        x = t_out - t_in
        m = cut_phases_kernel(td, tj, m, 0.0 if 0.0 > x else x, cd, cj)
        vmax, amax, jmax = phase_maxima_kernel(pv, pa, cd, cj, m)
        if not _piece_ok(k, vmax, amax, jmax, pc, rows, consts):
            return False
        t_in = t_next
    return True


# -- one step ----------------------------------------------------------------------------------


@njit(types.void(_W1, _ip, _ip, _f8, _f8, _f8, _W1, _W1, _ip), cache=True)
def _record(
    out: np.ndarray,
    off: int,
    cap: int,
    s: float,
    v: float,
    a: float,
    durs: np.ndarray,
    jerks: np.ndarray,
    n: int,
) -> None:
    """The profile record (see ``profile_record``) of ``n`` phases from ``(s, v, a)``; its
    breaks as ``ScalarProfile.__init__`` computes them."""
    out[off] = n
    d = off + 1
    j = d + cap
    t = j + cap
    c = cap + 1
    tb = 0.0
    out[t], out[t + c], out[t + 2 * c], out[t + 3 * c] = tb, s, v, a
    for i in range(n):
        T = durs[i]
        jk = jerks[i]
        out[d + i] = T
        out[j + i] = jk
        s += T * (v + T * (0.5 * a + T * jk / 6.0))
        v += T * (a + 0.5 * T * jk)
        a += T * jk
        tb += T
        k = t + 1 + i
        out[k], out[k + c], out[k + 2 * c], out[k + 3 * c] = tb, s, v, a


@njit(
    _ip(*(_f8,) * 9, _RO2, _RO3, _RO3, _RO1, _W1),
    cache=True,
)
def peek_kernel(
    s: float,
    v: float,
    a: float,
    dt: float,
    cap: float,
    S: float,
    A_min: float,
    J_min: float,
    ramp_c: float,
    pc: np.ndarray,
    rows: np.ndarray,
    geo: np.ndarray,
    consts: np.ndarray,
    out: np.ndarray,
) -> int:
    """Plan one step of ``dt`` from the path state ``(s, v, a)`` of a follower that is not done
    (the body of ``PathFollower.peek`` between its done test and its fallback).

    Path ``pc (P, PC_COLS)``, ``rows (P, n, 7)``, ``geo (P, 2, n)`` (see
    ``PathFollower._kernel_tables``); ``cap``: the speed cap; ``A_min``, ``J_min``,
    ``ramp_c``: the follower's look-ahead constants. Writes ``out (OUT_LEN,)``: the step's
    profile (record ``O_HEAD``) always, its end state (``O_END``) and the stop (profile record
    ``O_STOP``, limits ``O_LIM``) for STEP, the stop's start (the rest position for
    STEP_REST) for both; returns the status (FALLBACK:
    the step is not valid, the follower's held failsafe takes over).
    """
    pd = np.empty(H_MAX)
    pj = np.empty(H_MAX)
    td = np.empty(H_MAX)
    tj = np.empty(H_MAX)
    hd = np.empty(H_MAX)
    hj = np.empty(H_MAX)
    n_plan, A_f, J_f = _intended(
        s, v, a, dt, cap, S, A_min, J_min, ramp_c, pc, consts, pd, pj, td, tj
    )
    n = cut_phases_kernel(pd, pj, n_plan, dt, hd, hj)
    if n > H_CAP:  # never (see H_CAP); keeps the record in bounds
        return FALLBACK
    _record(out, O_HEAD, H_CAP, s, v, a, hd, hj, n)
    # the step's end (ScalarProfile.end) and peek's snapping of it
    e = O_HEAD + 1 + 2 * H_CAP + n
    c = H_CAP + 1
    s1, v1, a1 = out[e + c], out[e + 2 * c], out[e + 3 * c]
    if abs(v1) <= 1e-12 and abs(a1) <= 1e-9:
        v1, a1 = (0.0 if 0.0 > v1 else v1), 0.0
    s_tol = consts[C_STOL]
    if S - s1 <= s_tol and v1 <= consts[C_REST_V]:
        s1 = S if S < s1 else s1
    out[O_END] = s1
    out[O_END + 1] = v1
    out[O_END + 2] = a1
    if not (v1 >= 0.0 and s1 <= S + s_tol):
        return FALLBACK
    if not _step_ok(s, v, a, hd, hj, n, s1, pc, rows, consts, td, tj, pd, pj):
        return FALLBACK
    if not (math.isfinite(s1) and math.isfinite(v1) and math.isfinite(a1)):
        return FALLBACK
    status, ph, A_s, J_s, s_c, v_c = _plan_stop(s1, v1, a1, A_f, J_f, S, pc, rows, geo, consts)
    m = int(ph[0])
    for i in range(m):
        td[i] = ph[1 + i]
        tj[i] = ph[4 + i]
    _record(out, O_STOP, S_CAP, s_c, v_c, a1, td, tj, m)
    out[O_LIM] = A_s
    out[O_LIM + 1] = J_s
    return status
