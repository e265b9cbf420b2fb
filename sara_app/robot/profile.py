"""Scalar jerk-limited motion: the path coordinate ``s(t)`` as piecewise-constant-jerk phases
(time-optimal velocity changes under acceleration and jerk bounds, evaluation, maxima over
intervals). Used by the path follower for its steps and by the failsafe stops."""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "ScalarProfile",
    "cut_phases",
    "phase_maxima",
    "phases_at",
    "phases_end",
    "velocity_phases",
]


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


class ScalarProfile:
    """Piecewise-constant-jerk motion of a scalar ``s(t)``, ``t >= 0``, from ``(s0, v0, a0)``.

    Phase ``i`` runs over ``[tb[i], tb[i+1]]`` with jerk ``jerk[i]``; ``sb, vb, ab`` are the
    states at the breaks; ``start``, ``end``: ``(s, s', s'')`` at 0 and at ``duration``. After
    the last phase the motion continues with zero jerk (for a stop that is rest). Evaluation is
    vectorised over times.
    """

    __slots__ = (
        "durs", "jerks", "tb_l", "sb_l", "vb_l", "ab_l", "duration", "start", "end", "_np",
    )  # fmt: skip

    def __init__(
        self, s0: float, v0: float, a0: float, durs: list[float], jerks: list[float]
    ) -> None:
        self.durs = durs = list(durs)
        self.jerks = jerks = list(jerks)
        if len(durs) != len(jerks):
            raise ValueError(f"{len(durs)} phase durations but {len(jerks)} jerks")
        self.start = (s0, v0, a0)
        tb = [0.0]
        sb, vb, ab = [s0], [v0], [a0]
        s, v, a, t = s0, v0, a0, 0.0
        for T, j in zip(durs, jerks):
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

    @classmethod
    def _from_breaks(
        cls,
        durs: list[float],
        jerks: list[float],
        tb: list[float],
        sb: list[float],
        vb: list[float],
        ab: list[float],
    ) -> ScalarProfile:
        """The profile whose phases are ``durs``, ``jerks`` and whose break tables (``P + 1``
        each) are ``tb, sb, vb, ab`` as ``__init__`` computes them (a compiled caller, with the
        same recurrences); the lists are kept, not copied."""
        prof = cls.__new__(cls)
        prof.durs, prof.jerks = durs, jerks
        prof.tb_l, prof.sb_l, prof.vb_l, prof.ab_l = tb, sb, vb, ab
        prof.duration = tb[-1]
        prof.start = (sb[0], vb[0], ab[0])
        prof.end = (sb[-1], vb[-1], ab[-1])
        prof._np = None
        return prof

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
        for T, j in zip(self.durs, self.jerks):
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
