"""``sara-app bench --machine``: the machine's own stalls over a while, with nothing started
but the witnesses (:mod:`sara_app.ops.stalls`): is this machine fit for a 500 Hz cell?"""

from __future__ import annotations

import os
import time
from contextlib import nullcontext
from dataclasses import dataclass

from sara_app.bus.messages.robot import command_validity_s
from sara_app.ops import idle
from sara_app.ops.stalls import (
    PERIOD_S,
    PRIORITY,
    STALL_S,
    Stall,
    Witnesses,
    steal_s,
    stolen_share,
    summary,
)

CELL_PERIOD_S = 0.002
"""The control period the verdict judges against (500 Hz, the shipped scenarios')."""


@dataclass(frozen=True)
class MachineStalls:
    """What the witnesses saw over ``seconds``: ``stalls`` (longest first) on ``cpus``;
    ``refused``: why nothing was witnessed (None: witnessed); ``stolen``: the largest share
    of a CPU the host took meanwhile (the steal counter); ``idle``: where the CPUs' idle time
    went (:func:`sara_app.ops.idle.describe`)."""

    seconds: float
    cpus: tuple[int, ...]
    stalls: tuple[Stall, ...]
    refused: str | None
    stolen: float
    idle: str


def witnessed(seconds: float, idle_poll: bool = False) -> MachineStalls:
    """The machine's stalls over the next ``seconds`` with nothing started here but the
    witnesses (``sara-app bench --machine``); ``idle_poll``: the idle CPUs poll meanwhile
    (:func:`sara_app.ops.idle.idle_polling`, as a cell's machine should be set up)."""
    cpus = tuple(sorted(os.sched_getaffinity(0)))
    with idle.idle_polling() if idle_poll else nullcontext():
        idle0, s0, t0 = idle.idle_times_us(), steal_s(), time.monotonic()
        w = Witnesses()
        try:
            if w.refused is None:
                time.sleep(seconds)
        finally:  # a Ctrl-C too: no witness outlives the measurement
            stalls = w.stop()
        wall_s = time.monotonic() - t0
        shares = idle.idle_shares(idle0, idle.idle_times_us())
    stolen = stolen_share(s0, steal_s(), wall_s)
    idle_line = idle.describe(shares, idle.idle_driver())
    return MachineStalls(wall_s, cpus, tuple(stalls), w.refused, stolen, idle_line)


def report(m: MachineStalls) -> str:
    """``sara-app bench --machine``'s text: per CPU the stalls, a minute's worth and the
    longest; what the host took; what a cell makes of it."""
    lines = [
        f"The machine's own stalls over {m.seconds:.0f} s: a witness per CPU (SCHED_FIFO "
        f"{PRIORITY}, above a cell's processes) woke every {PERIOD_S * 1e3:g} ms; a wake-up "
        f"over {STALL_S * 1e3:g} ms late is a stall.",
        f"  {summary(m.stalls, m.refused)}",
    ]
    if m.refused is None:
        lines.append(f"  {'cpu':>5s} {'stalls':>7s} {'per minute':>11s} {'longest ms':>11s}")
        for cpu in m.cpus:
            late = [s.late_s for s in m.stalls if s.cpu == cpu]
            worst = f"{max(late) * 1e3:.1f}" if late else "-"
            per_min = 60.0 * len(late) / max(m.seconds, 1e-9)
            lines.append(f"  {cpu:5d} {len(late):7d} {per_min:11.1f} {worst:>11s}")
    lines.append(f"  the host took at most {100 * m.stolen:.2f} % of a CPU meanwhile (steal: "
                 "stalls like these barely move it)")  # fmt: skip
    lines.append(f"  {m.idle}")
    lines.append("  A 500 Hz cell's period is 2 ms: a cycle, a robot state or a command that "
                 "falls into a stall is late by as much; the reference controller brakes on "
                 "its own when its command runs out.")  # fmt: skip
    if m.refused is None:
        lines.append(f"  {verdict(m.stalls)}")
    return "\n".join(lines)


def verdict(stalls: tuple[Stall, ...] | list[Stall]) -> str:
    """What the longest stall means for a 500 Hz cell: over a command's validity
    (:data:`~sara_app.bus.messages.robot.COMMAND_VALID_MIN_S`) the command in force runs out
    during it wherever it falls on the worker or the bus; over a period, cycles and commands come
    late, and one that was already late may run out (``serve`` on the Intel Xeon VM, stalls of
    up to 7 ms: the controller braked on its own 1-6 times a minute); else nothing the cell
    feels."""
    valid_s = command_validity_s(CELL_PERIOD_S)
    longest = max((s.late_s for s in stalls), default=0.0)
    if longest > valid_s:
        return (f"Not fit for a 500 Hz cell as it is: a stall of {longest * 1e3:.1f} ms outlasts "
                f"a command's validity ({valid_s * 1e3:.0f} ms), so the robot's controller "
                "will brake on its own here (where the idle CPUs halt, measure again with "
                "--idle-poll: polling ones stall less).")  # fmt: skip
    if longest > CELL_PERIOD_S:
        return (f"Stalls up to {longest * 1e3:.1f} ms: longer than a period, shorter than a "
                f"command's validity ({valid_s * 1e3:.0f} ms): late cycles and commands, and "
                "now and then one that runs out before the next comes (the controller then "
                "brakes on its own).")  # fmt: skip
    return "No stall longer than a 500 Hz period: nothing a cell here would feel."
