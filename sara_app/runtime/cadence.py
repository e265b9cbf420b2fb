"""The worker's cycle phase, locked to the skeleton stream.

The worker cycles on its own clock (one command per control period). A skeleton that arrives
just after a cycle started waits for the next one: up to a whole period (2 ms at 500 Hz) of
extra age on every skeleton, spread uniformly when the tracker's and the worker's clocks are
unrelated, the same large wait every time when they happen to be locked badly. The reachable
sets grow with that age, and an operator sees it as latency.

:class:`PhaseLock` moves the cycle grid so that a cycle starts just after a skeleton arrives:
the cycle at ``stamp + tau`` (modulo the period) where ``tau``, a high quantile (``quantile``)
of the skeletons' delay from stamp to arrival, is learned from the skeletons themselves. It
never changes the control rate: it slews the phase by at most ``max_slew`` of a period per
cycle (a period of 2 ms +- 40 us at the default), so the controller's set points stay on
schedule (a command 40 us late: the robot is 40 us on the command's verified stop, which is
sound, and the next set point is met).

Reading a skeleton's delay: when the grid is locked (cycles at ``stamp + tau + k dt``), a
skeleton is first taken at ``lag = now - stamp = tau`` when it arrived within ``tau`` (a hit)
and at ``tau + dt`` or later when it did not (a miss). ``tau`` follows the quantile by the
Robbins-Monro rule ``tau += step * (miss - (1 - quantile))``: a miss raises it by almost a step,
a hit lowers it by ``1 - quantile`` of one (a five-hundredth at the default 0.998). The phase
error is the lag minus ``tau``, modulo the period; while it is larger than a quarter period the
grid is not locked and ``tau`` is left alone (a lag then says where the grid is, not how late
the skeleton was). A frame period that is not a multiple of the control period brings frames at
several phases of the grid (100 Hz on a 250 Hz grid: two); the lock then moves towards each in
turn, within the slew bound: no gain, no harm. One person's skeletons are followed (the
reference, kept until none came from them for :data:`REFERENCE_TIMEOUT_S`): people tracked by
unrelated trackers arrive at unrelated phases.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["REFERENCE_TIMEOUT_S", "PhaseLock"]

REFERENCE_TIMEOUT_S = 0.5
"""A reference person without a skeleton for this long is replaced by whoever comes next."""

_MAX_LAG_S = 0.25
"""Lags beyond this (either sign: a tracker's clock may be off) are not a transport delay:
ignored."""


@dataclass
class PhaseLock:
    """The phase corrections of a cycle grid of period ``dt_s`` (s).

    Each cycle: :meth:`observe` with the cycle's start time and the stamps of the skeletons
    it took (first time seen), then :meth:`slew_s` gives how much later (positive) or earlier
    (negative) than a period from now the next cycle starts, at most ``max_slew * dt_s``.
    """

    dt_s: float
    max_slew: float = 0.02
    quantile: float = 0.998
    step_s: float = 1e-4
    gain: float = 0.25
    """Share of a measured phase error corrected (the rest waits for the next skeleton: one
    skeleton's jitter moves the grid by a quarter of it)."""
    tau_s: float = 5e-4
    """The learned delay quantile (s); this value until the first skeletons."""
    pending_s: float = 0.0
    """Correction still to apply (s): positive later, negative earlier."""
    reference: str | None = None
    reference_seen_s: float = -math.inf
    hits: int = 0
    misses: int = 0

    def observe(self, now_s: float, stamps_s: dict[str, float]) -> None:
        """The cycle that started at ``now_s`` (the clock of the stamps) took skeletons stamped
        ``stamps_s`` (per person id); non-finite or implausible stamps are ignored."""
        if self.reference not in stamps_s:
            if not stamps_s or now_s - self.reference_seen_s < REFERENCE_TIMEOUT_S:
                return
            self.reference = min(stamps_s)
        lag = now_s - stamps_s[self.reference]
        if not math.isfinite(lag) or abs(lag) > _MAX_LAG_S:
            return
        self.reference_seen_s = now_s
        dt = self.dt_s
        error = math.remainder(lag - self.tau_s, dt)  # in [-dt/2, dt/2]: > 0 the cycle is late
        if abs(error) <= dt / 4:  # locked: the lag says whether it arrived within tau
            miss = lag > self.tau_s + dt / 2
            self.hits += not miss
            self.misses += miss
            self.tau_s += self.step_s * (miss - (1.0 - self.quantile))
            self.tau_s = min(max(self.tau_s, -_MAX_LAG_S), _MAX_LAG_S)
        self.pending_s = -self.gain * error

    def slew_s(self) -> float:
        """This cycle's share of the pending correction (s), within ``+- max_slew * dt_s``."""
        limit = self.max_slew * self.dt_s
        s = min(max(self.pending_s, -limit), limit)
        self.pending_s -= s
        return s
