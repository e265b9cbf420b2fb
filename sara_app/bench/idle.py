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

from pathlib import Path

CPU_ROOT = Path("/sys/devices/system/cpu")


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
