"""What a loaded machine loses on the bus, with every key in one zenoh priority and in the
contract's lanes (``sara-app bench --lanes``).

Every publisher of the cell drops a message (zenoh's ``DROP`` congestion control) when its
priority's transmit queue stays full for 1 ms; a process whose transmit thread waits for a CPU
fills it with one control cycle's burst. This bench publishes, at the control rate, what a
worker puts in one cycle (its command, verdict, display message, status and an answer: the last
two far rarer in a cell, here every cycle, the worst case; the contract's example messages, a
display message smaller than a real one) from one session to a subscriber in
another, through a router, while ``hogs`` busy processes load the machine; once with every key
at zenoh's default priority (as before the lanes), once at its lane's
(:func:`sara_app.bus.session.priority_of`), and counts what each key lost. It also times each
cycle's puts: a put into a full queue waits (up to 1 ms) before it drops, and in a worker that
wait is its control loop's; and counts the commands that arrived later than a command's
shortest validity (``COMMAND_VALID_MIN_S`` after their put): a transmit queue deep enough to
keep a command can still deliver it too late to be of use.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from collections import Counter
from typing import Any, NamedTuple

import numpy as np
import zenoh

from sara_app.bus import keys
from sara_app.bus.examples import example_messages
from sara_app.bus.messages import COMMAND_VALID_MIN_S, encode
from sara_app.bus.session import Bus, free_port, priority_of
from sara_app.errors import ParameterError

CYCLE_KINDS = ("robot_command", "verdict", "occupancy", "status", "params_ack")
"""What a worker puts in one control cycle, in its order (``sara_app.runtime``)."""
MODES = ("one lane", "lanes")


class LaneRun(NamedTuple):
    """One run of one mode: messages lost per kind (of the run's cycles), the 99th
    percentile of the time one cycle's puts took (us), and the commands that arrived but
    later than a command's shortest validity after their put (``COMMAND_VALID_MIN_S``: a
    controller would discard them, as good as lost)."""

    lost: dict[str, int]
    puts_p99_us: float
    commands_late: int


def default_hogs() -> int:
    """Busy processes beside the publisher unless told: two per CPU."""
    return 2 * (os.cpu_count() or 1)


def _hogs(n: int) -> list[subprocess.Popen[bytes]]:
    return [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]


def _publishers(bus: Bus, cell: str, lanes: bool) -> list[tuple[str, Any, bytes]]:
    """``(kind, zenoh publisher, payload)`` per cycle kind, as the worker declares them; at
    zenoh's default priority unless ``lanes``."""
    examples = example_messages()
    out = []
    for kind in CYCLE_KINDS:
        key_expr, msg = keys.key(kind, cell), examples[kind][1]
        priority = priority_of(key_expr) if lanes else zenoh.Priority.DATA
        pub = bus.session.declare_publisher(
            key_expr, congestion_control=zenoh.CongestionControl.DROP, priority=priority,
            express=kind not in keys.BATCHED_KINDS,
        )  # fmt: skip
        out.append((kind, pub, encode(msg)))
    return out


def _run(port: int, cell: str, lanes: bool, rounds: int, period_s: float, hogs: int
         ) -> LaneRun:  # fmt: skip
    """``rounds`` cycles of one mode."""
    heard: Counter[str] = Counter()
    lock = threading.Lock()
    put_at, heard_at = np.full(rounds, np.nan), np.full(rounds, np.nan)  # commands, by seq
    commands = _numbered_commands(rounds)

    def hear(sample: zenoh.Sample) -> None:
        kind = keys.parse_key(str(sample.key_expr)).kind
        if kind == "robot_command":
            heard_at[int(json.loads(sample.payload.to_bytes())["seq"])] = time.monotonic()
        with lock:
            heard[kind] += 1

    with Bus.client(port) as sender, Bus.client(port) as receiver:
        listener = receiver.session.declare_subscriber(keys.cell_keys(cell), hear)
        pubs = _publishers(sender, cell, lanes)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not all(
            p.matching_status.matching for _, p, _ in pubs
        ):
            time.sleep(0.01)
        puts_s = np.zeros(rounds)
        busy = _hogs(hogs)
        try:
            time.sleep(0.2)  # the hogs running
            for r in range(rounds):
                t0 = time.perf_counter()
                put_at[r] = time.monotonic()
                for kind, pub, payload in pubs:
                    pub.put(commands[r] if kind == "robot_command" else payload)
                puts_s[r] = time.perf_counter() - t0
                time.sleep(period_s)
        finally:
            for proc in busy:
                proc.kill()
                proc.wait()
        time.sleep(1.0)  # what is still on its way arrives
        listener.undeclare()
        for _, pub, _ in pubs:
            pub.undeclare()
    with lock:
        lost = {kind: rounds - heard[kind] for kind in CYCLE_KINDS}
    late = int(np.sum(heard_at - put_at > COMMAND_VALID_MIN_S))  # NaN (lost): not late
    return LaneRun(lost, float(np.percentile(puts_s, 99)) * 1e6, late)


def _numbered_commands(rounds: int) -> list[bytes]:
    """The contract's example command once per round, numbered by ``seq`` (the round), so that
    the receiver tells each one's delay."""
    msg = example_messages()["robot_command"][1]
    return [encode(msg.model_copy(update={"seq": r})) for r in range(rounds)]


def bench_lanes(
    rounds: int = 2000, period_s: float = 0.002, hogs: int | None = None, runs: int = 2
) -> dict[str, list[LaneRun]]:
    """Per mode (:data:`MODES`), per run: messages lost per cycle kind out of ``rounds`` and
    the cycle's puts' time, with ``hogs`` busy processes (default: :func:`default_hogs`)
    beside the publisher; the modes alternate so that a machine's drift shows in both."""
    n_hogs = default_hogs() if hogs is None else hogs
    if rounds < 1 or runs < 1 or n_hogs < 0 or not period_s >= 0:
        raise ParameterError(
            f"bench --lanes: rounds {rounds}, runs {runs}, hogs {n_hogs}, period {period_s} s; "
            "expected rounds and runs >= 1, hogs and period >= 0"
        )
    port = free_port()
    out: dict[str, list[LaneRun]] = {mode: [] for mode in MODES}
    with Bus.router(port):
        for run in range(runs):
            for mode in MODES:
                cell = f"lanes{run}{mode[0]}"
                out[mode].append(_run(port, cell, mode == "lanes", rounds, period_s, n_hogs))
    return out


def report(runs: dict[str, list[LaneRun]], rounds: int, hogs: int) -> str:
    """A table: per mode and kind, the messages lost in each run (of ``rounds``), and each
    run's commands late and 99th percentile of a cycle's puts."""
    beside = f"{hogs} busy process{'' if hogs == 1 else 'es'} beside"
    rows = [(kind, [", ".join(str(r.lost[kind]) for r in runs[m]) for m in MODES])
            for kind in CYCLE_KINDS]  # fmt: skip
    rows.append(("commands late", [", ".join(str(r.commands_late) for r in runs[m])
                                   for m in MODES]))  # fmt: skip
    rows.append(("puts p99 (us)", [", ".join(f"{r.puts_p99_us:.0f}" for r in runs[m])
                                   for m in MODES]))  # fmt: skip
    width = max(16, *(len(c) for _, cells in rows for c in cells))
    lines = [f"messages lost of {rounds} per key and run, {beside}", ""]
    lines.append(f"{'key':16s} " + "  ".join(f"{m:>{width}s}" for m in MODES))
    for name, cells in rows:
        lines.append(f"{name:16s} " + "  ".join(f"{c:>{width}s}" for c in cells))
    return "\n".join(lines)
