"""``serve``'s supervision of a cell's processes (router, controller, worker, replayer).

- A child that exits is started again after a backoff (0.5 s, doubling to 10 s; back to 0.5 s
  once a child has run for 30 s), and counted.
- A worker that stops cycling while its process lives (hung, stopped) is killed and restarted:
  once it has published verdicts, no verdict for ``HUNG_AFTER_S`` (two status heartbeats) is a
  hang, counted from the later of its start and the router's (after a router restart the bus
  was down, not the worker) and never while the router is down (:meth:`Supervisor.hang_age`).
  Silence alone does not tell a hung worker from a stalled bus (a router that stops answering
  stays alive): a silent worker is killed when its main thread has not run for
  ``HUNG_AFTER_S`` (stopped, deadlocked: ``/proc``), or when the bus has delivered another
  process's message since its newest verdict (a worker that runs but does not publish). A
  stalled router with a cycling worker behind it is left alone. Meanwhile the API shows the
  cell offline with its mode unknown, and the controller brakes along the last verified stop on
  its own.
- A router stopped (SIGSTOP, a debugger's stop: its state in ``/proc``) for
  ``ROUTER_STOPPED_AFTER_S`` is killed and restarted; a shorter stop resumes by itself. A router
  that hangs while it runs (a deadlock) cannot be told from an idle one by its CPU time (an idle
  router uses none either, as while its worker restarts) and is left alone: the controllers
  brake on their own meanwhile.
- Children never outlive ``serve``: each asks the kernel to kill it when its parent dies
  (``sara_app.tethered``), and ``stop()`` ends them in order.
"""

from __future__ import annotations

import logging
import math
import signal
import subprocess
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

log = logging.getLogger("sara_app.serve")

BACKOFF_S = (0.5, 10.0)
STABLE_S = 30.0
HUNG_AFTER_S = 2.0
ROUTER_STOPPED_AFTER_S = 5.0
"""A router stopped this long is restarted (``sara-app soak --chaos`` stops it for at most 2 s,
which it survives: its sessions reconnect within a second of the SIGCONT)."""


def _stat_fields(path: str) -> list[bytes]:
    """The fields of a ``/proc`` ``stat`` file after the command name (state first, then ppid,
    ...; ``utime`` and ``stime`` at 11 and 12); empty when it cannot be read."""
    try:
        with open(path, "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()
    except (OSError, IndexError):
        return []


@dataclass
class Child:
    """One supervised process: ``start()`` spawns it."""

    name: str
    start: Callable[[], subprocess.Popen[bytes]]
    proc: subprocess.Popen[bytes] | None = None
    started_s: float = 0.0
    restarts: int = 0
    backoff_s: float = BACKOFF_S[0]
    due_s: float | None = None  # a restart is due at this time
    cpu_ticks: int = -1  # the main thread's CPU time at the last poll (clock ticks; -1: none)
    ran_s: float = 0.0  # when the main thread was last seen to run
    stopped_s: float | None = None  # since when the process is seen stopped (None: running)

    def spawn(self, now: float) -> None:
        self.proc = self.start()
        self.started_s = self.ran_s = now
        self.due_s = None
        self.cpu_ticks = -1
        self.stopped_s = None

    def stopped_for(self, now: float) -> float:
        """How long the process has been seen stopped (its state ``T`` or ``t`` in ``/proc``:
        SIGSTOP, a debugger), counted from the first poll that saw it; 0 while it runs or
        when ``/proc`` cannot be read (call once a poll: it records the time)."""
        fields = [] if self.proc is None else _stat_fields(f"/proc/{self.proc.pid}/stat")
        if not fields or fields[0] not in (b"T", b"t"):
            self.stopped_s = None
            return 0.0
        if self.stopped_s is None:
            self.stopped_s = now
        return now - self.stopped_s

    def ran_recently(self, now: float) -> bool:
        """Whether the main thread has used CPU within ``HUNG_AFTER_S`` (call once a poll: it
        records the CPU time). Unreadable (no ``/proc``): False, so that silence decides."""
        if self.proc is None:
            return False
        fields = _stat_fields(f"/proc/{self.proc.pid}/task/{self.proc.pid}/stat")
        try:
            ticks = int(fields[11]) + int(fields[12])  # utime + stime
        except (IndexError, ValueError):
            return False
        if ticks != self.cpu_ticks:
            if self.cpu_ticks >= 0:  # the first reading is the baseline (ran_s: the start)
                self.ran_s = now
            self.cpu_ticks = ticks
        return now - self.ran_s < HUNG_AFTER_S

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None


class Supervisor:
    """Starts, watches and restarts children; ``poll(now, last_verdict_s)`` once a frame."""

    def __init__(
        self,
        children: list[Child],
        worker: str | tuple[str, ...] = "worker",
        router: str = "router",
    ) -> None:
        """``worker``: the name of the worker child, or of every cell's worker."""
        self.children = children
        self.workers = (worker,) if isinstance(worker, str) else tuple(worker)
        self.worker, self.router = self.workers[0], router

    def start(self, names: tuple[str, ...] | None = None) -> None:
        """Start the children not started yet (only ``names`` when given)."""
        now = time.monotonic()
        for c in self.children:
            if c.proc is None and (names is None or c.name in names):
                c.spawn(now)

    def poll(
        self,
        now: float,
        verdict_age_s: float | None | Mapping[str, float | None],
        bus_since: bool | Mapping[str, bool] = False,
    ) -> list[str]:
        """Restart what died or hung; returns what happened (for the log). ``verdict_age_s``:
        the age of the cell's newest verdict received since the worker last started (None:
        none yet; :meth:`hang_age`), or per worker child name for several cells;
        ``bus_since``: whether another process's message (the controller's status) came
        through the router after that verdict, likewise."""
        events = []
        for c in self.children:
            if c.due_s is not None:
                if now >= c.due_s:
                    c.spawn(now)
                    events.append(f"{c.name} restarted (#{c.restarts})")
                continue
            kill_why = None  # why a child that runs is killed (then restarted below)
            if c.name in self.workers:
                age, bus = self._of(verdict_age_s, c.name), self._of(bus_since, c.name)
                ran = c.ran_recently(now)  # every poll: it records the CPU time
                silent = c.alive and age is not None and age > HUNG_AFTER_S
                if silent and (not ran or bool(bus)):
                    kill_why = f"hung ({age:.1f} s without a verdict)"
            if c.name == self.router and c.alive:
                stopped_s = c.stopped_for(now)  # every poll: it records since when
                if stopped_s >= ROUTER_STOPPED_AFTER_S:
                    kill_why = f"stopped for {stopped_s:.1f} s"
            if kill_why is not None and c.proc is not None:
                c.proc.send_signal(signal.SIGKILL)
                c.proc.wait()
                events.append(f"{c.name} {kill_why}: killed")
            if not c.alive:
                code = None if c.proc is None else c.proc.returncode
                if now - c.started_s > STABLE_S:
                    c.backoff_s = BACKOFF_S[0]
                c.due_s = now + c.backoff_s
                c.backoff_s = min(2 * c.backoff_s, BACKOFF_S[1])
                c.restarts += 1
                events.append(f"{c.name} exited (code {code}): restart in {c.due_s - now:.1f} s")
        for e in events:
            log.warning("supervisor: %s", e)
        return events

    def _of(self, value: Any, name: str) -> Any:
        """``value`` of worker child ``name``: its entry of a mapping, or the value itself for
        the (first) worker; None for any other child."""
        if isinstance(value, Mapping):
            return value.get(name)
        return value if name == self.worker else None

    def verdicts_due_s(self, worker: str | None = None) -> float:
        """Since when the worker's verdicts can reach the supervisor (monotonic clock): the
        later of the worker's last start and the router's (after a router restart every session
        reconnects, about 2 s; until the first verdict after that, no hang is diagnosed: the bus
        was down, not the worker); ``inf`` while the router is down (dead, or waiting for its
        restart: its backoff grows to 10 s, and the silence is the bus's)."""
        w = self.worker if worker is None else worker
        if any(c.name == self.router and not c.alive for c in self.children):
            return math.inf
        return max(c.started_s for c in self.children if c.name in (w, self.router))

    def hang_age(
        self, now: float, received_s: float | None, worker: str | None = None
    ) -> float | None:
        """The age to judge ``worker``'s hang on (for :meth:`poll`): ``now - received_s`` when
        its newest verdict (received at ``received_s``, monotonic clock; None: none) came
        through the worker and the router running now, else None (no hang can be told)."""
        if received_s is None or not received_s > self.verdicts_due_s(worker):
            return None
        return now - received_s

    def status(self) -> dict[str, dict[str, object]]:
        return {
            c.name: {
                "pid": None if c.proc is None else c.proc.pid,
                "running": c.alive,
                "restarts": c.restarts,
            }
            for c in self.children
        }

    def stop(self, timeout_s: float = 5.0) -> None:
        """Stop every child (the last started first: the router ends after its users)."""
        for c in self.children:
            c.due_s = None
        stop_processes([c.proc for c in reversed(self.children) if c.proc is not None], timeout_s)


def stop_processes(procs: list[subprocess.Popen[bytes]], timeout_s: float = 5.0) -> None:
    """SIGTERM to each, then wait ``timeout_s`` in all, then SIGKILL what is left. A cell
    process that runs stops on SIGTERM as on Ctrl-C (``bus.process``, ``bus.router``: the loop
    ends, the session closes); one still starting up has no handler yet and ends at once,
    where SIGINT would print a KeyboardInterrupt traceback from the middle of its imports
    (three of them under ``serve``'s own error when its API port was taken)."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    t_end = time.monotonic() + timeout_s
    for p in procs:
        try:
            p.wait(timeout=max(t_end - time.monotonic(), 0.1))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
