"""Scalar jerk-limited motion: the path coordinate ``s(t)`` as piecewise-constant-jerk phases
(time-optimal velocity changes under acceleration and jerk bounds, evaluation, maxima over
intervals). Used by the path follower for its steps and by the failsafe stops. The phase
functions are the planner's compiled ones (:mod:`sara_app.robot.planning_kernels`), called
with lists."""

from __future__ import annotations

import numpy as np

from sara_app.robot.planning_kernels import (
    cut_phases_kernel,
    phase_maxima_kernel,
    phases_at_kernel,
    phases_end_kernel,
    velocity_phases_kernel,
)

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
    ph = velocity_phases_kernel(v0, a0, vt, A, J)
    n = int(ph[0])
    return list(ph[1 : 1 + n]), list(ph[4 : 4 + n])


def phases_end(
    s: float, v: float, a: float, durs: list[float], jerks: list[float]
) -> tuple[float, float, float]:
    """State ``(s, v, a)`` at the end of at most three phases (a velocity change)."""
    n = len(durs)
    if n > 3 or len(jerks) != n:
        raise ValueError(f"{n} phase durations and {len(jerks)} jerks; expected at most 3 each")
    pad = (0.0,) * (3 - n)
    return phases_end_kernel(s, v, a, (float(n), *durs, *pad, *jerks, *pad))


def phases_at(
    s: float, v: float, a: float, durs: list[float], jerks: list[float], t: float
) -> tuple[float, float, float]:
    """State at time ``t`` (after the last phase the motion goes on with zero jerk)."""
    d, j = _arrays(durs, jerks)
    return phases_at_kernel(s, v, a, d, j, d.shape[0], t)


def phase_maxima(
    v: float, a: float, durs: list[float], jerks: list[float]
) -> tuple[float, float, float]:
    """Exact ``max s'``, ``max |s''|``, ``max |jerk|`` over the phases from ``(v, a)``."""
    d, j = _arrays(durs, jerks)
    return phase_maxima_kernel(v, a, d, j, d.shape[0])


def cut_phases(durs: list[float], jerks: list[float], t: float) -> tuple[list[float], list[float]]:
    """The phases over ``[0, t]``, padded with a zero-jerk phase if they end earlier."""
    d, j = _arrays(durs, jerks)
    out_d, out_j = np.empty(d.shape[0] + 1), np.empty(d.shape[0] + 1)
    m = cut_phases_kernel(d, j, d.shape[0], t, out_d, out_j)
    return out_d[:m].tolist(), out_j[:m].tolist()


def _arrays(durs: list[float], jerks: list[float]) -> tuple[np.ndarray, np.ndarray]:
    if len(durs) != len(jerks):
        raise ValueError(f"{len(durs)} phase durations but {len(jerks)} jerks")
    return np.array(durs, dtype=np.float64), np.array(jerks, dtype=np.float64)


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
