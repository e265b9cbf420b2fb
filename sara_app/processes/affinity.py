"""Which CPUs ``sara-app serve``'s processes run on: each cell's worker on a CPU of its own where
the machine has more CPUs than cells, everything else (router, controllers, replayers, the
dashboard and API) on the others.

Why: a live cell's processes share caches when they share CPUs, and every Python step then runs
on cold caches (docs/performance.md: a robot-state decode takes 7 µs in a loop and about 49 µs
in the live worker). Measured on a 2-core machine with one cell, the worker alone on one CPU
and the rest on the other halved the router's CPU time per cycle and cut the controller's by a
third, and the worker's loop no longer shares its CPU with anything but its own I/O threads.

A process is pinned from its start (``taskset -c`` before ``exec``, so every thread it creates
inherits the set); without ``taskset``, or with too few CPUs, nothing is pinned and the
scheduler places everything as before.
"""

from __future__ import annotations

import logging
import os
import shutil
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger("sara_app.serve")


@dataclass(frozen=True)
class CpuPlan:
    """``workers``: per cell (in order) the CPUs of its worker; ``rest``: everyone else's."""

    workers: tuple[frozenset[int], ...]
    rest: frozenset[int]

    def worker(self, i: int) -> frozenset[int]:
        return self.workers[i]


def cpu_plan(cells: int, cpus: set[int] | None = None) -> CpuPlan | None:
    """The CPUs of ``cells`` workers and of the rest among ``cpus`` (default: the ones this
    process may use): the highest-numbered CPUs one per worker, the others for the rest; None
    (no pinning) unless there are more CPUs than cells."""
    have = sorted(os.sched_getaffinity(0) if cpus is None else cpus)
    if cells < 1 or len(have) <= cells:
        return None
    workers = tuple(frozenset({c}) for c in have[len(have) - cells :])
    return CpuPlan(workers, frozenset(have[: len(have) - cells]))


def pinned(cmd: list[str], cpus: frozenset[int] | None) -> list[str]:
    """``cmd`` started on ``cpus`` only (through ``taskset -c``; as is without a set or
    without ``taskset``)."""
    if not cpus:
        return cmd
    tool = shutil.which("taskset")
    if tool is None:
        log.debug("no 'taskset' command: %s runs on any CPU", cmd[0])
        return cmd
    return [tool, "-c", ",".join(str(c) for c in sorted(cpus)), *cmd]


def pin_threads(pid: int, cpus: frozenset[int]) -> int:
    """Move every thread of ``pid`` (this process: ``os.getpid()``) onto ``cpus``; returns how
    many were moved (threads that ended meanwhile are skipped)."""
    moved = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            os.sched_setaffinity(int(task.name), cpus)
            moved += 1
        except (OSError, ValueError):
            continue
    return moved


@contextmanager
def placed_as_serve(pin: bool = True) -> Iterator[CpuPlan | None]:
    """For a benchmark that starts one cell itself: the plan of one cell's CPUs (None without
    ``pin`` or a CPU to spare), this process's threads (the display side, the listener) on the
    plan's rest while inside, and back on the CPUs they had on leaving."""
    plan = cpu_plan(1) if pin else None
    before = frozenset(os.sched_getaffinity(0))
    if plan is not None:
        pin_threads(os.getpid(), plan.rest)
    try:
        yield plan
    finally:
        if plan is not None:
            pin_threads(os.getpid(), before)
