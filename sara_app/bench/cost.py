"""``sara-app bench --live``: what a live cell costs per control cycle, measured on the cell as
``sara-app serve`` runs it (its router, reference controller, worker and replayer, each a
process of its own at serve's priorities), with 1 and 4 replayed people at the scenario's rate.

Per run and load, two phases of ``seconds`` each:

1. **CPU**: for every cell process, the CPU time (user + system, all threads, from
   ``/proc/<pid>/stat``; of it, the threads of zenoh's runtimes, by their names) and the
   context switches (voluntary and not, all threads, from
   ``/proc/<pid>/task/*/status``) over the phase, divided by the verdicts received: the cost of
   one control cycle, and how the machine's CPUs idled meanwhile (polling or halted:
   :mod:`sara_app.ops.idle`). This process listens to the verdicts only (as serve's registry
   does).
   The skeleton -> verdict latency comes from the same verdicts: a verdict's ``stamp_s -
   skeleton_age_s`` is the stamp of the skeleton it used, so the first verdict that used a
   skeleton gives its stamp -> reception time here (one clock: this machine's). The stamp is
   the tracker's measurement time: it includes the tracker's own time before it publishes.
2. **Messages**: every message on the cell's keys counted and sized per key kind, per cycle
   (listening to all of them costs the router a copy of each: not done while measuring CPU);
   and the latency from each skeleton's **publication** (its zenoh timestamp, which the
   replayer's session sets when it puts the message) to the first verdict received that used
   it: the issue's "skeleton published -> verdict received", under this phase's extra load.

Through both phases a witness per CPU (:mod:`sara_app.ops.stalls`) notes every stall of the
machine itself over 1 ms: a latency p99 taken while the machine stalled is the machine's. The
witnesses' own wake-ups (about 25 µs of CPU every 2 ms on each CPU, ahead of the cell's
threads) are in the latencies measured, not in the processes' CPU.

The rows are the median over ``runs`` runs (and the spread); ``docs/performance.md`` holds the
numbers measured with it.
"""

from __future__ import annotations

import gc
import json
import os
import re
import tempfile
import threading
import time
from collections import defaultdict
from contextlib import nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sara_app.bus import keys
from sara_app.bus.session import Bus, free_port
from sara_app.ops import idle
from sara_app.ops.stalls import Stall, Witnesses, summary

PROCESSES = ("router", "controller", "worker", "replayer")
PEOPLE = (1, 4)
SPOTS_M = ((1.3, 0.1), (1.3, -0.6), (1.3, 0.75), (1.9, 0.1))
"""Where the replayed people stand (x, y) in the default cell: in front of the bench."""


@dataclass
class ProcessCost:
    cpu_us: float
    switches: float
    zenoh_us: float = 0.0
    """Of ``cpu_us``, zenoh's threads (the rest: Python and what it calls)."""


@dataclass
class LoadCost:
    """One load (``people``) measured over runs: per process, CPU us and context switches per
    cycle (one value per run); latency samples (us); messages and bytes per cycle per key kind
    (from the last run); verdicts per second per run."""

    people: int
    scenario: str
    rate_hz: float
    per_process: dict[str, list[ProcessCost]] = field(default_factory=lambda: defaultdict(list))
    latency_us: list[np.ndarray] = field(default_factory=list)
    """Per run, ``(N, 2)``: each skeleton's wait for a cycle and the cycle + verdict delivery
    (:func:`_latencies`)."""
    published_us: list[np.ndarray] = field(default_factory=list)
    """Per run, ``(N, 2)`` from the second phase: each skeleton's stamp -> publication (the
    tracker's own time) and publication -> verdict received (:func:`_published_latencies`)."""
    verdict_hz: list[float] = field(default_factory=list)
    messages: dict[str, tuple[float, float]] = field(default_factory=dict)
    idle: list[dict[str, float]] = field(default_factory=list)
    """Per run, the share of the CPUs' idle time in each cpuidle state during the CPU phase
    (:mod:`sara_app.ops.idle`): a CPU that halts between messages wakes them cold."""
    idle_driver: str = "none"
    stalls: list[list[Stall]] = field(default_factory=list)
    """Per run, the machine's own stalls during its measurements (:mod:`sara_app.ops.stalls`:
    what makes a p99 the machine's rather than the cell's)."""
    stalls_refused: str | None = None
    """Why no stall was witnessed (None: witnessed)."""


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process and all its threads."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


ZENOH_THREAD = re.compile(r"(rx|tx|app|net|acc)-\d+")
"""The names of the threads of zenoh's runtimes (its I/O and its own work, no Python)."""


def _zenoh_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process's living zenoh threads (:data:`ZENOH_THREAD`)."""
    total = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            text = (task / "stat").read_text()
        except (FileNotFoundError, ProcessLookupError):
            continue  # a thread that ended
        name, fields = text[text.index("(") + 1 : text.rindex(")")], text.rsplit(")", 1)[1].split()
        if ZENOH_THREAD.fullmatch(name):
            total += int(fields[11]) + int(fields[12])
    return total / os.sysconf("SC_CLK_TCK")


def _switches(pid: int) -> int:
    """Context switches (voluntary and not) of every living thread of a process (a thread that
    ended takes its counts along: the cell's threads live as long as their process)."""
    n = 0
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            for line in (task / "status").read_text().splitlines():
                if "ctxt_switches:" in line:
                    n += int(line.split()[1])
        except (FileNotFoundError, ProcessLookupError):
            continue  # a thread that ended
    return n


def scenario_with_people(
    scenario: str, people: int, folder: Path, phase_lock: bool = False
) -> Path:
    """The scenario's file with ``people`` copies of its first person at :data:`SPOTS_M`, the
    worker's cycle phase locked to the skeletons or not (``phase_lock``)."""
    from sara_app.scenario import load_scenario

    data = load_scenario(scenario).model_dump(mode="json")
    first = data["humans"][0]
    data["humans"] = [
        {**first, "id": f"p{i + 1}", "position_m": list(SPOTS_M[i % len(SPOTS_M)])}
        for i in range(people)
    ]
    data["inputs"]["cycle_phase_lock"] = phase_lock
    path = folder / f"{scenario}-{people}p.json"
    path.write_text(json.dumps(data))
    return path


def _latencies(received: list[tuple[float, float, dict[str, float]]]) -> np.ndarray:
    """Skeleton publication -> verdict reception (us) from ``(received, verdict stamp,
    skeleton ages)``: per person and skeleton stamp, the first verdict that used it; shape
    ``(N, 2)``: the wait for a cycle (the skeleton's age when the cycle started) and the
    cycle and the verdict's delivery (cycle start -> received), whose sum is the latency."""
    first = _first_use(received).values()
    return np.array(
        [(age * 1e6, (t_recv - stamp_s) * 1e6) for age, t_recv, stamp_s in first]
    ).reshape(-1, 2)


def _first_use(
    received: list[tuple[float, float, dict[str, float]]],
) -> dict[tuple[str, float], tuple[float, float, float]]:
    """``(person, skeleton stamp)`` -> ``(its age at the cycle, s; when that verdict was
    received; the verdict's stamp)``, from the first verdict received that used the
    skeleton."""
    first: dict[tuple[str, float], tuple[float, float, float]] = {}
    for t_recv, stamp_s, ages in received:
        for h, age in ages.items():
            first.setdefault((h, round(stamp_s - age, 6)), (age, t_recv, stamp_s))
    return first


def _verdicts(hub: Bus, cell: str, seconds: float) -> list[tuple[float, float, dict[str, float]]]:
    """``(received, stamp, skeleton ages)`` of the cell's verdicts over ``seconds``, with this
    process's garbage collector off (a collection pausing this listener would show as latency
    of the cell). The listener sleeps in the subscription's channel, woken by each verdict: a
    polling listener would add its own polling period to every latency."""
    from sara_app.bus.codec import Decoder
    from sara_app.bus.messages import VerdictMsg

    got: list[tuple[float, float, dict[str, float]]] = []
    sub = hub.subscribe(keys.verdict_key(cell), Decoder(), capacity=4096)
    timer = threading.Timer(seconds, sub.close)  # ends receive() below
    gc.disable()
    timer.start()
    try:
        while (drained := sub.receive()) is not None:
            for d in drained.messages:
                if isinstance(d.msg, VerdictMsg):
                    got.append((d.recv_s, d.msg.stamp_s, d.msg.skeleton_age_s))
    finally:
        gc.enable()
        timer.cancel()
        sub.close()
    return got


Heard = tuple[dict[str, tuple[int, int]], dict[tuple[str, float], float], list[Any]]


def _messages(hub: Bus, cell: str, seconds: float) -> Heard:
    """Messages and bytes per key kind on the cell's keys over ``seconds``; each skeleton's
    publication time (its zenoh timestamp: the replayer's session stamps what it puts) by
    ``(person, skeleton stamp)``; and the verdicts as :func:`_verdicts` gives them."""
    counts: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    published: dict[tuple[str, float], float] = {}
    verdicts: list[Any] = []
    lock = threading.Lock()

    def seen(sample: Any) -> None:
        t_recv = time.time()
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        try:
            k = keys.parse_key(key)
            kind = k.kind
        except Exception:  # noqa: BLE001 - count what is not ours under its key
            k, kind = None, key
        with lock:
            c = counts[kind]
            c[0] += 1
            c[1] += len(payload)
        try:
            if kind == "skeleton" and k is not None and sample.timestamp is not None:
                stamp = round(float(json.loads(payload)["stamp_s"]), 6)
                published[(str(k.human_id), stamp)] = sample.timestamp.get_time().timestamp()
            elif kind == "verdict":
                v = json.loads(payload)
                verdicts.append((t_recv, float(v["stamp_s"]), v["skeleton_age_s"]))
        except (ValueError, KeyError, TypeError):
            pass  # not a message of the contract: counted above, not timed

    sub = hub.session.declare_subscriber(f"sara/{cell}/**", seen)
    time.sleep(seconds)
    sub.undeclare()
    with lock:
        return {k: (v[0], v[1]) for k, v in counts.items()}, published, verdicts


def _published_latencies(
    received: list[tuple[float, float, dict[str, float]]],
    published: dict[tuple[str, float], float],
) -> np.ndarray:
    """Per skeleton whose publication time is known (``published`` by ``(person, stamp)``),
    from the first verdict received that used it (``received`` as :func:`_latencies` takes
    it): ``(N, 2)`` us, the tracker's own time from stamp to publication, and publication ->
    verdict received (the issue's latency: one clock, this machine's)."""
    out = []
    for (h, t_skel), (_, t_recv, _) in _first_use(received).items():
        t_pub = published.get((h, t_skel))
        if t_pub is not None:
            out.append(((t_pub - t_skel) * 1e6, (t_recv - t_pub) * 1e6))
    return np.array(out).reshape(-1, 2)


def _measure(hub: Bus, cell: str, pids: dict[str, int], seconds: float, out: LoadCost) -> None:
    witnesses = Witnesses()  # above the cell's processes; about 1.5 % of each CPU, their own
    try:
        _measure_phases(hub, cell, pids, seconds, out)
    finally:
        out.stalls.append(witnesses.stop())
        out.stalls_refused = witnesses.refused


def _measure_phases(
    hub: Bus, cell: str, pids: dict[str, int], seconds: float, out: LoadCost
) -> None:
    cpu0 = {n: _cpu_s(p) for n, p in pids.items()}
    zenoh0 = {n: _zenoh_cpu_s(p) for n, p in pids.items()}
    sw0 = {n: _switches(p) for n, p in pids.items()}
    idle0 = idle.idle_times_us()
    t0 = time.monotonic()
    got = _verdicts(hub, cell, seconds)
    span = time.monotonic() - t0
    out.idle.append(idle.idle_shares(idle0, idle.idle_times_us()))
    out.idle_driver = idle.idle_driver()
    cycles = max(len(got), 1)
    for n, p in pids.items():
        cpu_us, zenoh_us = (
            1e6 * (f(p) - s0[n]) / cycles for f, s0 in ((_cpu_s, cpu0), (_zenoh_cpu_s, zenoh0))
        )
        out.per_process[n].append(ProcessCost(cpu_us, (_switches(p) - sw0[n]) / cycles, zenoh_us))
    out.verdict_hz.append(len(got) / span)
    out.latency_us.append(_latencies(got))
    msgs, published, heard = _messages(hub, cell, seconds)
    out.published_us.append(_published_latencies(heard, published))
    n_cycles = max(out.verdict_hz[-1] * seconds, 1.0)
    out.messages = {k: (n / n_cycles, b / n_cycles) for k, (n, b) in sorted(msgs.items())}


def bench_live(
    scenario: str = "punches", people: tuple[int, ...] = PEOPLE, seconds: float = 10.0,
    runs: int = 3, pin_cpus: bool = True, robot_encoding: str = "compact",
    phase_lock: bool = False, idle_poll: bool = False,
) -> list[LoadCost]:  # fmt: skip
    """Each load measured ``runs`` times on a fresh cell (see the module notes); ``pin_cpus``:
    the worker on a CPU of its own and the rest (this process too) on the others, as serve
    does where the machine has a CPU to spare; ``robot_encoding``: of states and commands;
    ``phase_lock``: the scenario's ``inputs.cycle_phase_lock``; ``idle_poll``: the idle CPUs
    poll instead of halting while it measures (:func:`sara_app.ops.idle.idle_polling`)."""
    from sara_app.processes.affinity import placed_as_serve
    from sara_app.scenario import load_scenario

    results = []
    with idle.idle_polling() if idle_poll else nullcontext(), placed_as_serve(pin_cpus) as plan:
        with tempfile.TemporaryDirectory(prefix="sara-bench-live-") as tmp:
            for n in people:
                path = str(scenario_with_people(scenario, n, Path(tmp), phase_lock))
                load = LoadCost(n, scenario, 1.0 / load_scenario(path).shield.dt_s)
                for _ in range(runs):
                    _run(path, plan, seconds, load, robot_encoding)
                results.append(load)
    return results


def _run(path: str, plan: Any, seconds: float, load: LoadCost, robot_encoding: str) -> None:
    """One fresh cell on ``path`` as serve starts it (CPUs per ``plan``), measured into
    ``load``."""
    from sara_app.ops.supervisor import stop_processes
    from sara_app.processes.serve import connect_when_listening, start_cell, start_router

    port, cell = free_port(), "benchlive"
    router = start_router(port, None if plan is None else plan.rest)
    procs = [router]
    try:
        with connect_when_listening(port, router) as hub:
            procs += start_cell(cell, path, port, plan, robot_encoding)
            _wait_running(hub, cell)
            time.sleep(2.0)  # the replayer's people in, the robot moving
            pids = dict(zip(PROCESSES, (p.pid for p in procs), strict=True))
            _measure(hub, cell, pids, seconds, load)
    finally:
        stop_processes(procs[::-1])


def _wait_running(hub: Bus, cell: str, wait_s: float = 120.0) -> None:
    """Until the worker sends verdicts (its kernels load first)."""
    t_end = time.monotonic() + wait_s
    while time.monotonic() < t_end:
        if _verdicts(hub, cell, 0.2):
            return
    raise RuntimeError(f"cell {cell!r} sent no verdict within {wait_s:g} s")


def report(loads: list[LoadCost]) -> str:
    """The measurements as text tables (CPU per cycle, latency, messages per cycle)."""
    lines = []
    for load in loads:
        runs = len(load.verdict_hz)
        hz = ", ".join(f"{x:.0f}" for x in load.verdict_hz)
        lines.append(f"{load.scenario}, {load.people} people, {load.rate_hz:.0f} Hz control, "
                     f"{runs} runs (verdicts/s: {hz})")  # fmt: skip
        lines.append(f"  {'process':12s} {'CPU us/cycle':>14s} {'(runs)':>22s} "
                     f"{'switches/cycle':>15s} {'of which zenoh':>15s}")  # fmt: skip
        total, total_zenoh = np.zeros(runs), np.zeros(runs)
        for name in PROCESSES:
            costs = load.per_process[name]
            cpu = np.array([c.cpu_us for c in costs])
            zenoh = np.array([c.zenoh_us for c in costs])
            total, total_zenoh = total + cpu, total_zenoh + zenoh
            sw = np.median([c.switches for c in costs])
            spread = " ".join(f"{x:.0f}" for x in cpu)
            lines.append(f"  {name:12s} {np.median(cpu):14.0f} {spread:>22s} {sw:15.1f} "
                         f"{np.median(zenoh):15.0f}")  # fmt: skip
        spread = " ".join(f"{x:.0f}" for x in total)
        lines.append(f"  {'all':12s} {np.median(total):14.0f} {spread:>22s} {'':15s} "
                     f"{np.median(total_zenoh):15.0f}")  # fmt: skip
        states = {name for run in load.idle for name in run}
        shares = {n: float(np.median([run.get(n, 0.0) for run in load.idle])) for n in states}
        lines.append(f"  {idle.describe(shares, load.idle_driver)} (median of the runs)")
        if load.stalls:
            stalls = [x for run in load.stalls for x in run]
            lines.append(f"  the machine: {summary(stalls, load.stalls_refused)} (all runs)")
        stamped = [a for a in load.latency_us if a.size]
        published = [a for a in load.published_us if a.size]
        for what, pick, parts, note in (
            ("skeleton stamped -> verdict received", lambda a: a.sum(1), stamped,
             " (median of the runs)"),
            ("  of which: waiting for a cycle", lambda a: a[:, 0], stamped, ""),
            ("  the cycle and the verdict's delivery", lambda a: a[:, 1], stamped, ""),
            ("skeleton published -> verdict received", lambda a: a[:, 1], published,
             " (second phase)"),
            ("  the tracker's own: stamped -> published", lambda a: a[:, 0], published, ""),
        ):  # fmt: skip
            if parts:
                p50, p99 = np.median([np.percentile(pick(a), [50, 99]) for a in parts], 0) / 1e3
                lines.append(f"  {what}: p50 {p50:.2f} ms, p99 {p99:.2f} ms{note}")
        lines.append(f"  {'key':22s} {'messages/cycle':>15s} {'bytes/cycle':>12s}")
        for kind, (m, b) in load.messages.items():
            lines.append(f"  {kind:22s} {m:15.2f} {b:12.0f}")
        lines.append("")
    return "\n".join(lines)
