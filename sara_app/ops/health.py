"""What ``sara-app serve`` says at INFO while it runs: a cell's state changes as they happen
(worker started, offline, a fault with its cause and when it clears) and one health line per
cell every minute: the verdict rate against the control rate, the worker's cycle time, how old
the skeletons were at decision time (tracker period, transport and the cycle's own wait), the
share of time moving, slowed,
braking or faulted, command delivery at the robot's controller (lost, late, expired, and why it
braked on its own) and the faults seen; watching the machine (``serve --watch-machine``), a
line of the machine's own stalls (:mod:`sara_app.ops.stalls`).

The counters are kept per cell by the live registry (:class:`VerdictCounters`, updated with each
verdict: a few increments, no allocation); :class:`HealthLog` reads them and the controller's
own counts from the registry's snapshot and logs differences over the minute.
"""

from __future__ import annotations

import logging
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from sara_app.bus.messages import VerdictMsg
from sara_app.bus.verdict_words import verdict_state
from sara_app.ops.stalls import Stall, summary

log = logging.getLogger("sara_app.health")

AGE_BIN_S = 1e-4
"""Width of a skeleton-age histogram bin (0.1 ms)."""
CYCLE_BIN_S = 1e-5
"""Width of a cycle-time histogram bin (10 us)."""
N_BINS = 2000
"""Bins per histogram (ages to 200 ms, cycles to 20 ms); the last also holds the rest."""
STATES = ("moving", "slowed", "braking", "rest", "fault")
CAUSE_WORDS = {
    "controller": "the controller's loop was held up",
    "worker": "the worker's command came too late",
    "lost": "commands lost on the bus",
    "delivery": "commands delayed on the bus",
}
"""Why the controller braked on its own, in words (``ControllerStatusMsg.braking_causes``)."""
OFFLINE_WORDS = "offline: no fresh verdict (the robot's controller brakes on its own)"


@dataclass
class VerdictCounters:
    """Counts since the watcher first saw the cell: verdicts, verdicts per state, histograms of
    the worker's cycle time and of the oldest skeleton's age at decision time, and the newest
    fault."""

    verdicts: int = 0
    states: dict[str, int] = field(default_factory=lambda: dict.fromkeys(STATES, 0))
    cycle: np.ndarray = field(default_factory=lambda: np.zeros(N_BINS, np.int64))
    age: np.ndarray = field(default_factory=lambda: np.zeros(N_BINS, np.int64))
    last_fault: str = ""

    def add(self, v: VerdictMsg) -> None:
        """One verdict."""
        self.verdicts += 1
        state = verdict_state(v)
        self.states[state] += 1
        if state == "fault" and v.faults:
            self.last_fault = v.faults[0]
        self.cycle[_bin(1e-6 * v.cycle_time_us, CYCLE_BIN_S)] += 1
        if v.skeleton_age_s:
            self.age[_bin(max(v.skeleton_age_s.values()), AGE_BIN_S)] += 1

    def copy(self) -> VerdictCounters:
        return VerdictCounters(self.verdicts, dict(self.states), self.cycle.copy(),
                               self.age.copy(), self.last_fault)  # fmt: skip


def _bin(x_s: float, bin_s: float) -> int:
    return min(max(int(x_s / bin_s), 0), N_BINS - 1)


def percentile_s(hist: np.ndarray, q: float, bin_s: float) -> float | None:
    """The ``q``-th percentile of a histogram's samples in s (a bin's upper edge: never less
    than the sample); None without samples."""
    n = int(hist.sum())
    if n == 0:
        return None
    k = int(np.searchsorted(np.cumsum(hist), q / 100.0 * n))
    return bin_s * (min(k, N_BINS - 1) + 1)


class MachineWatch(Protocol):
    """What the health log reads of the machine's witnesses
    (:class:`sara_app.ops.stalls.Witnesses`)."""

    def take(self) -> list[Stall]: ...

    def ended(self) -> list[int]: ...


class Registry(Protocol):
    """What the health log reads (``sara_app.api.registry.CellRegistry``)."""

    def cell(self, name: str) -> dict[str, Any] | None: ...

    def counters(self, name: str) -> VerdictCounters | None: ...


@dataclass
class _Seen:
    counters: VerdictCounters | None = None
    controller: dict[str, Any] | None = None
    online: bool | None = None
    state: str | None = None
    fault: str | None = None
    fault_since_s: float | None = None
    offline_said: bool = False
    first_s: float | None = None
    """When the first verdict was seen (the first line's rate counts from then)."""


class HealthLog:
    """State changes at once and a health line per cell every ``interval_s``; ``rates_hz``:
    cell -> its control rate. Call :meth:`poll` often (serve's frame loop: 20 Hz)."""

    def __init__(
        self,
        registry: Registry,
        rates_hz: dict[str, float],
        interval_s: float = 60.0,
        clock: Callable[[], float] = time.monotonic,
        machine: MachineWatch | None = None,
    ) -> None:
        self.registry, self.rates_hz, self.interval_s = registry, rates_hz, interval_s
        self.clock = clock
        self.machine = machine
        """The machine's witnesses (:class:`sara_app.ops.stalls.Witnesses`), their stalls said
        once a line; None: not watched."""
        self._seen = {c: _Seen() for c in rates_hz}
        self._last_line_s = clock()

    def poll(self) -> None:
        now = self.clock()
        for cell, seen in self._seen.items():
            self._changes(cell, seen, now)
        if now - self._last_line_s >= self.interval_s:
            span_s, self._last_line_s = now - self._last_line_s, now
            for cell, seen in self._seen.items():
                since = span_s if seen.first_s is None else min(span_s, now - seen.first_s)
                log.info("%s", self.line(cell, seen, max(since, 1e-3)))
            if self.machine is not None:
                m = self.machine
                log.info("%s", machine_line(m.take(), span_s, m.ended()))

    def _changes(self, cell: str, seen: _Seen, now: float) -> None:
        snap = self.registry.cell(cell)
        if snap is None:
            return
        online, state = bool(snap.get("online")), snap.get("state")
        if state != seen.state and state is not None:
            log.info("%s: worker %s (scenario %s)", cell, state, snap.get("scenario"))
        if not online and seen.online:
            log.info("%s: %s", cell, OFFLINE_WORDS)
            seen.offline_said = True
        elif online and seen.offline_said:
            log.info("%s: fresh verdicts again", cell)
            seen.offline_said = False
        seen.online, seen.state = online, state
        if seen.first_s is None and snap.get("verdicts_received"):
            seen.first_s = now
        fault = (snap.get("faults") or [None])[0] if snap.get("verdict_state") == "fault" else None
        if fault is not None and seen.fault is None:
            log.info("%s: fault: %s", cell, fault)
            seen.fault_since_s = now
        elif fault is None and seen.fault is not None and seen.fault_since_s is not None:
            log.info("%s: fault cleared after %.1f s", cell, now - seen.fault_since_s)
        seen.fault = fault

    def line(self, cell: str, seen: _Seen, span_s: float) -> str:
        """The health line of ``cell`` over the last ``span_s`` (updates what was seen)."""
        now_c = self.registry.counters(cell)
        snap = self.registry.cell(cell) or {}
        ctl = snap.get("controller")
        before, ctl_before = seen.counters, seen.controller
        seen.counters, seen.controller = now_c, ctl
        if now_c is None:
            return f"{cell}: no verdict received yet"
        d = _difference(now_c, before)
        rate = self.rates_hz.get(cell, 0.0)
        share = f" ({100 * d.verdicts / (span_s * rate):.1f} % of {rate:.0f} Hz)" if rate else ""
        parts = [f"{cell}: {d.verdicts / span_s:.0f} verdicts/s{share}"]
        if d.verdicts:
            parts.append(f"cycle p50 {_us(percentile_s(d.cycle, 50, CYCLE_BIN_S))}, "
                         f"p99 {_us(percentile_s(d.cycle, 99, CYCLE_BIN_S))}")  # fmt: skip
            if d.age.sum():
                parts.append(f"skeleton age at decision p50 "
                             f"{_ms(percentile_s(d.age, 50, AGE_BIN_S))}, "
                             f"p99 {_ms(percentile_s(d.age, 99, AGE_BIN_S))}")  # fmt: skip
            shares = [f"{s} {100 * n / d.verdicts:.0f} %" for s, n in d.states.items() if n]
            parts.append(", ".join(shares))
        parts.append(_controller_words(ctl, ctl_before))
        faults = d.states["fault"]
        parts.append(f"faults: {faults} verdicts, the last: {now_c.last_fault}" if faults
                     else "faults: none")  # fmt: skip
        return "; ".join(parts)


def machine_line(stalls: list[Stall], span_s: float, ended: list[int]) -> str:
    """The machine's own stalls over the last ``span_s``, per CPU: what a controller that
    braked on its own ("its loop was held up", "commands delayed") may have met; ``ended``:
    CPUs whose witness has ended (their stalls unseen: said, never counted as none)."""
    text = f"machine: {summary(stalls, None)} in the last {span_s:.0f} s"
    if ended:
        text = (f"machine: NOT WATCHED on CPU {', '.join(map(str, ended))} (its witness ended); "
                f"{text.removeprefix('machine: ')}")  # fmt: skip
    per_cpu = Counter(s.cpu for s in stalls)
    if per_cpu:
        text += " (" + ", ".join(f"CPU {c}: {n}" for c, n in sorted(per_cpu.items())) + ")"
    return text


def _difference(now: VerdictCounters, before: VerdictCounters | None) -> VerdictCounters:
    if before is None:
        return now
    return VerdictCounters(
        now.verdicts - before.verdicts,
        {s: now.states[s] - before.states[s] for s in STATES},
        now.cycle - before.cycle,
        now.age - before.age,
        now.last_fault,
    )


def _ms(x_s: float | None) -> str:
    return "n/a" if x_s is None else f"{1e3 * x_s:.1f} ms"


def _us(x_s: float | None) -> str:
    return "n/a" if x_s is None else f"{1e6 * x_s:.0f} us"


_COUNTS = ("commands_received", "commands_lost", "commands_late", "commands_expired",
           "commands_refused", "braking_events")  # fmt: skip


def _controller_words(ctl: dict[str, Any] | None, before: dict[str, Any] | None) -> str:
    """Command delivery at the controller over the minute, and why it braked on its own."""
    if ctl is None:
        return "controller: no status"
    if not ctl.get("online"):
        return "controller: offline (no status for over 2 s)"
    if (
        before is not None
        and ctl.get("worker_runs") == before.get("worker_runs")
        and all(int(ctl.get(k, 0)) >= int(before.get(k, 0)) for k in _COUNTS)
    ):
        d = {k: int(ctl.get(k, 0)) - int(before.get(k, 0)) for k in _COUNTS}
        causes_before = before.get("braking_causes") or {}
    else:  # the first line, or a restarted controller: its counts since it started
        d = {k: int(ctl.get(k, 0)) for k in _COUNTS}
        causes_before = {}
    received = d["commands_received"]
    text = (f"controller: {received} commands, {d['commands_lost']} lost, "
            f"{d['commands_late']} late, {d['commands_expired']} expired")  # fmt: skip
    braked = d["braking_events"]
    if braked:
        causes = {c: n - int(causes_before.get(c, 0))
                  for c, n in (ctl.get("braking_causes") or {}).items()}  # fmt: skip
        why = ", ".join(f"{CAUSE_WORDS.get(c, c)}: {n}" for c, n in causes.items() if n > 0)
        times = "once" if braked == 1 else f"{braked} times"
        text += f", braked on its own {times}" + (f" ({why})" if why else "")
    if ctl.get("receive_failed"):
        text += ", reading commands late (its wait for them failed: restart it)"
    return text
