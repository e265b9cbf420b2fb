"""How the machine's CPUs spent their idle time: polling, or halted (the kernel's cpuidle
states).

What a live cell's cycle costs depends on it (docs/performance.md, "Cycles start cold"): a CPU
that halts when idle (a VM's ``haltpoll``, a bare-metal C-state) hands its caches and branch
predictors to whatever runs meanwhile, and each message then wakes a cold process; a CPU that
polls keeps them, at the price of a core busy even when nothing runs (a PM QoS latency request
of 0, as ``/dev/cpu_dma_latency`` or a tuned latency profile makes). ``sara-app bench --live``
says which states the measured interval used, so that rows from machines or settings that idle
differently are not compared as if they were alike.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from sara_app.errors import AccessError

CPU_ROOT = Path("/sys/devices/system/cpu")
QOS_DEVICE = Path("/dev/cpu_dma_latency")
"""The kernel's CPU latency (PM QoS) request: a 32-bit value in us, held while the file is
open (the kernel drops it when the file closes, also when its process dies)."""


def idle_times_us(root: Path = CPU_ROOT) -> dict[str, int]:
    """Time (us) the CPUs spent in each cpuidle state since boot, summed over CPUs, by the
    state's name; empty where the kernel exposes no cpuidle states (a container without
    ``/sys``, another system)."""
    times: dict[str, int] = {}
    for state in sorted(root.glob("cpu[0-9]*/cpuidle/state[0-9]*")):
        try:
            name = (state / "name").read_text().strip()
            used_us = int((state / "time").read_text())
        except (OSError, ValueError):
            continue  # a CPU taken offline meanwhile, or a file this kernel does not have
        times[name] = times.get(name, 0) + used_us
    return times


def idle_shares(before: dict[str, int], after: dict[str, int]) -> dict[str, float]:
    """Share of the idle time between two :func:`idle_times_us` readings spent in each state
    (summing to 1; empty when no idle time was recorded)."""
    spent = {name: max(after[name] - before.get(name, 0), 0) for name in after}
    total = sum(spent.values())
    return {} if total <= 0 else {name: t / total for name, t in spent.items()}


def idle_driver(root: Path = CPU_ROOT) -> str:
    """The cpuidle driver (``haltpoll``, ``intel_idle``, ``acpi_idle``...), or ``"none"``."""
    try:
        return (root / "cpuidle" / "current_driver").read_text().strip() or "none"
    except OSError:
        return "none"


def describe(shares: dict[str, float], driver: str) -> str:
    """One line: where the idle time went, largest share first."""
    if not shares:
        return f"idle CPUs: no cpuidle states to read (driver {driver})"
    parts = ", ".join(
        f"{100 * s:.0f} % {name!r}" for name, s in sorted(shares.items(), key=lambda x: -x[1])
    )
    return f"idle CPUs: {parts} (cpuidle driver {driver}; 'POLL' keeps the caches warm)"


@contextmanager
def idle_polling(device: Path = QOS_DEVICE) -> Iterator[None]:
    """While inside, a CPU latency request of 0 us is held: the idle CPUs poll instead of
    entering any state that takes time to leave. Raises :class:`AccessError` where the request
    cannot be made (the device is root's on most systems)."""
    try:
        fd = os.open(device, os.O_WRONLY)
    except OSError as e:
        raise AccessError(
            f"cannot request polling idle CPUs through {device}: {e.strerror}; it takes write "
            "access to that device (root on most systems)"
        ) from e
    try:
        os.write(fd, struct.pack("i", 0))
        yield
    finally:
        os.close(fd)
