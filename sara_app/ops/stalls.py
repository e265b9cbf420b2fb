"""The machine's own stalls, witnessed: how often a CPU of this machine runs nothing of the
cell's for a millisecond or more (``sara-app serve --watch-machine``'s health lines, ``sara-app
bench --machine`` and beside ``--live``'s measurements; the test suite's reruns of period tests
read the same witnesses).

A witness is a process pinned to one CPU under ``SCHED_FIFO`` at :data:`PRIORITY`, above every
thread of a cell (its processes ask for 10), that sleeps :data:`PERIOD_S` at a time. A wake-up
more than :data:`STALL_S` late was held up by nothing of the cell's user space, which never runs
ahead of it: by the machine (a host that ran the virtual CPU late, or the kernel, which
preempts no kernel code on a ``PREEMPT_NONE`` build). A 500 Hz cell feels such a stall: a
cycle, a state or a command that falls into it is late by as much, and the reference
controller brakes on its own when its command runs out. On the Intel Xeon VM of 2026-12-05, idle
CPUs polling, a thread like this one alone on the machine woke 2-6 ms late 2-8 times a minute,
on either CPU, while the kernel's steal counter moved by 0.07 % of a CPU
(docs/measurements/2026-12-05-unseen-stalls.md): the steal counter does not show them.

Run as a script (``python stalls.py CPU``, what :class:`Witnesses` starts: this file imports
nothing but the standard library, so a witness starts in tens of milliseconds) it prints
``ready`` once it runs as asked (``no real-time: ...`` and exits 3 where the class is refused:
then it would wait behind the cell and witness the cell's load, not the machine), then one
line ``<wall time s> <late s>`` per stall (at most one a period: its reader keeps up); it exits
on SIGTERM or when its parent has gone, and leaves a Ctrl-C (SIGINT) to its parent.
"""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass

PRIORITY = 80
PERIOD_S = 0.002
"""A stall of at least a period is seen whenever it comes (a wake-up falls into it); the
witness's own share of its CPU: 1.3-1.4 % on the Intel Xeon VM of 2026-12-05 (about 25 µs of
CPU a wake-up, kernel included, taken ahead of the cell's threads)."""
STALL_S = 0.001
"""The wake-ups of a thread like this one on a polling CPU are 0.10-0.14 ms late at p99
(docs/measurements/2026-12-02-test-machine-stalls.md)."""
KEPT = 10_000
"""The stalls :meth:`Witnesses.stop` returns at most (the newest): a long watch on a machine
that stalls all the time keeps bounded memory."""
REFUSED = 3
"""The witness's exit status where ``SCHED_FIFO`` is refused."""
READY_WAIT_S = 10.0
STOP_WAIT_S = 10.0


def witness(cpu: int) -> int:
    """The witness of ``cpu`` (see the module notes); its exit status."""
    os.sched_setaffinity(0, {cpu})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PRIORITY))
    except OSError as e:
        print(f"no real-time: {e}", flush=True)
        return REFUSED
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C is its parent's: it stops us
    parent = os.getppid()
    print("ready", flush=True)
    next_s = time.monotonic()
    while True:
        next_s += PERIOD_S
        time.sleep(max(next_s - time.monotonic(), 0.0))
        late_s = time.monotonic() - next_s
        if late_s > STALL_S:
            print(f"{time.time() - late_s:.4f} {late_s:.4f}", flush=True)
            next_s = time.monotonic()  # one stall, one line: the schedule starts again
        if int(next_s) != int(next_s - PERIOD_S) and os.getppid() != parent:
            return 0  # the parent has gone (checked once a second)


@dataclass(frozen=True)
class Stall:
    """A wake-up of ``cpu``'s witness ``late_s`` late; ``start_s``: when it was due (wall s)."""

    cpu: int
    start_s: float
    late_s: float


class Witnesses:
    """One witness per CPU this process may use, from construction to :meth:`stop`, each read
    by a thread of this process as it reports. None where real-time scheduling is refused
    (:attr:`refused` says why): a witness would then see the cell's load, not the machine."""

    def __init__(self) -> None:
        self.refused: str | None = None
        self._procs: list[tuple[int, subprocess.Popen[str]]] = []
        self._readers: list[threading.Thread] = []
        self._lock = threading.Lock()
        self._new: list[Stall] = []
        self._kept: deque[Stall] = deque(maxlen=KEPT)
        for cpu in sorted(os.sched_getaffinity(0)):
            try:
                proc = subprocess.Popen([sys.executable, "-I", "-S", __file__, str(cpu)],
                                        stdout=subprocess.PIPE, text=True)  # fmt: skip
            except OSError as e:  # no process to spare: unwatched, not a crash of the caller
                self.refused = f"no witness started: {e}"
                self.stop()
                return
            self._procs.append((cpu, proc))
        for _cpu, proc in self._procs:
            first = _first_line(proc)
            if first != "ready":
                self.refused = first
                self.stop()
                return
        for cpu, proc in self._procs:
            reader = threading.Thread(target=self._read, args=(cpu, proc), daemon=True,
                                      name=f"stall-witness-{cpu}")  # fmt: skip
            reader.start()
            self._readers.append(reader)

    def _read(self, cpu: int, proc: subprocess.Popen[str]) -> None:
        if proc.stdout is None:
            return
        for line in proc.stdout:  # until the witness ends
            try:
                stall = _stall(cpu, line)
            except ValueError:  # not a stall's line (a witness prints nothing else)
                continue
            with self._lock:
                self._new.append(stall)
                self._kept.append(stall)

    def take(self) -> list[Stall]:
        """The stalls reported since the last take, in the order they came."""
        with self._lock:
            new, self._new = self._new, []
        return new

    def ended(self) -> list[int]:
        """The CPUs whose witness has ended before :meth:`stop` (killed, or out of memory):
        their stalls are no longer seen, which no count of stalls may hide."""
        return [cpu for cpu, proc in self._procs if proc.poll() is not None]

    def stop(self) -> list[Stall]:
        """Stop the witnesses; the stalls they saw (the last :data:`KEPT`), longest first (none
        where refused)."""
        for _cpu, proc in self._procs:
            proc.terminate()
        for _cpu, proc in self._procs:
            try:
                proc.wait(timeout=STOP_WAIT_S)
            except subprocess.TimeoutExpired:  # a hung witness must not hang its caller
                proc.kill()
                proc.wait()
        for reader in self._readers:
            reader.join(timeout=STOP_WAIT_S)
        for _cpu, proc in self._procs:
            if proc.stdout is not None:
                proc.stdout.close()
        self._procs, self._readers = [], []
        with self._lock:
            seen = list(self._kept) if self.refused is None else []
        return sorted(seen, key=lambda s: s.late_s, reverse=True)


def _first_line(proc: subprocess.Popen[str]) -> str:
    """A witness's first line (``ready``, or why not), waited for at most
    :data:`READY_WAIT_S`."""
    out = proc.stdout
    if out is None:
        return "no output"
    ready, _, _ = select.select([out], [], [], READY_WAIT_S)
    return (out.readline().strip() or "the witness ended") if ready else "no answer"


def _stall(cpu: int, line: str) -> Stall:
    start_s, late_s = line.split()
    return Stall(cpu, float(start_s), float(late_s))


def steal_s() -> list[float]:
    """Seconds each CPU's virtual CPU was runnable but not run by the host, since boot (the
    8th value of each ``cpuN`` line of /proc/stat, in clock ticks); empty where unreadable."""
    try:
        with open("/proc/stat") as f:
            rows = [ln.split() for ln in f if ln.startswith("cpu") and ln[3].isdigit()]
        return [int(r[8]) / os.sysconf("SC_CLK_TCK") for r in rows]
    except (OSError, IndexError, ValueError):
        return []


def stolen_share(before: list[float], after: list[float], wall_s: float) -> float:
    """The largest share of one CPU the host took between two :func:`steal_s` readings."""
    return max((b - a for a, b in zip(before, after)), default=0.0) / max(wall_s, 1e-9)


def summary(stalls: list[Stall] | tuple[Stall, ...], refused: str | None) -> str:
    """One line: how many stalls, the longest, or why none was witnessed."""
    if refused is not None:
        return (f"not witnessed: {refused} (a witness needs SCHED_FIFO: CAP_SYS_NICE or an "
                "rtprio limit, docs/deployment.md \"The machine\")")  # fmt: skip
    if not stalls:
        return f"no stall of over {STALL_S * 1e3:g} ms on any CPU"
    longest = max(s.late_s for s in stalls)
    return (f"{len(stalls)} stall{'s' if len(stalls) != 1 else ''} of over {STALL_S * 1e3:g} ms "
            f"on its CPUs, the longest {longest * 1e3:.1f} ms")  # fmt: skip


if __name__ == "__main__":
    sys.exit(witness(int(sys.argv[1])))
