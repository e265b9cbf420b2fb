"""``sara-app bench --cells``: many cells on one router, each with its own worker process, each
fed people at a tracker's rate; for each cells x people load, every cell's skeleton -> verdict
latency and whether it keeps its control rate.

Set-up as the single-cell latency benchmark (:mod:`sara_app.bench.bus`): this process hosts the
router; ``N`` workers run ``empty_cell`` at a 2 ms cycle (started with it) in processes of
their own at the real-time priority ``serve`` gives them (where the system permits); per cell
one thread publishes ``P`` people (standing 1.5-3 m from the robot) at ``rate_hz``, paced on
the clock, with a tracker frame listing them. A load passes when every cell's latency p99 is
below ``LATENCY_P99_MS`` and every cell keeps its rate (verdicts at 90 % of 1 / dt or more,
cycle p99 below dt).
"""

from __future__ import annotations

import tempfile
import threading
import time
from typing import Any

import numpy as np

from sara_app.bench.bus import (
    TRACKER_NOISE_M,
    Row,
    first_verdict_latencies,
    scenario_at_dt,
)
from sara_app.bus import keys
from sara_app.bus.heartbeat import Heartbeat
from sara_app.bus.messages import SkeletonMsg
from sara_app.sim.motions import measured

LATENCY_P99_MS = 5.0
DT_S = 0.002
"""The cells' control period: 500 Hz, as the default cell of ``serve`` (at 4 ms the latency's
p99 is bounded below by about one period plus one cycle and two hops, over 5 ms)."""
LOADS: tuple[tuple[int, int], ...] = ((1, 1), (1, 4), (2, 1), (2, 2), (2, 4), (3, 1), (3, 2),
                                      (4, 1), (5, 1), (6, 1))  # fmt: skip
"""(cells, people per cell) measured, in order (issue 33 asks for 6 cells x 1 person)."""


def _people(n: int) -> list[np.ndarray]:
    from sara_app.human.scripted import joints, standing

    return [joints(standing((1.5 + 0.5 * (i // 4), -0.9 + 0.6 * (i % 4)), 0.0)) for i in range(n)]


def _publish(pubs: list[Any], ys: list[np.ndarray], rate_hz: float, seconds: float,
             sent: dict[str, dict[float, int]]) -> None:  # fmt: skip
    """Every person's skeleton at ``rate_hz`` for ``seconds`` (stamps recorded per person)."""
    period, t_next = 1.0 / rate_hz, time.monotonic()
    rng = np.random.default_rng(0)
    for i in range(int(seconds * rate_hz)):
        delay = t_next - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        for k, (pub, y) in enumerate(zip(pubs, ys, strict=True)):
            t = time.time()
            sent[f"p{k}"][t] = i
            y_meas = measured(y, TRACKER_NOISE_M, rng)  # a real tracker never repeats a skeleton
            pub.put(SkeletonMsg.from_arrays("full", y_meas, seq=pub.next_seq(), stamp_s=t))
        t_next += period


def _load(
    hub: Any, cells: list[str], people: int, rate_hz: float, seconds: float,
    publishers: dict[str, Any],
) -> Row:  # fmt: skip
    """One load; ``publishers``: the skeleton publishers by key, kept between the loads of one
    router so that each person's ``seq`` keeps rising (a new publisher would start again at 1,
    and the worker would refuse its first messages as out of order)."""
    received: dict[str, list[tuple[float, bytes]]] = {c: [] for c in cells}
    subs = [hub.session.declare_subscriber(
        keys.verdict_key(c), lambda s, c=c: received[c].append((time.time(), s.payload.to_bytes())))
        for c in cells]  # fmt: skip
    sent: dict[str, dict[str, dict[float, int]]] = {
        c: {f"p{k}": {} for k in range(people)} for c in cells
    }
    ys = _people(people)
    threads = []
    for c in cells:
        pubs = []
        for k in range(people):
            key = keys.skeleton_key(c, f"p{k}")
            if key not in publishers:
                publishers[key] = hub.publisher(key)
            pubs.append(publishers[key])
        threads.append(threading.Thread(target=_publish, daemon=True,
                                        args=(pubs, ys, rate_hz, seconds, sent[c])))  # fmt: skip
    t0 = time.monotonic()
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    elapsed = time.monotonic() - t0
    time.sleep(0.2)
    for s in subs:
        s.undeclare()
    worst_p99, worst_p50, worst_rate, worst_cycle = 0.0, 0.0, np.inf, 0.0
    for c in cells:
        lat, cyc = first_verdict_latencies(received[c], sent[c], c)
        if not lat.size or not cyc.size:
            return (f"{len(cells)} cells x {people} people", np.nan, np.nan, f"{c}: no verdict")
        worst_p50 = max(worst_p50, float(np.median(lat)))
        worst_p99 = max(worst_p99, float(np.percentile(lat, 99)))
        worst_rate = min(worst_rate, cyc.size / (elapsed + 0.2) * DT_S)
        worst_cycle = max(worst_cycle, float(np.percentile(cyc, 99)))
    ok = worst_p99 < LATENCY_P99_MS * 1e3 and worst_rate >= 0.9 and worst_cycle < DT_S * 1e6
    note = (f"worst cell: rate {100 * worst_rate:.0f} % of 1/dt, cycle p99 {worst_cycle:.0f} us;"
            f" {'PASSES' if ok else 'fails'}")  # fmt: skip
    return (f"{len(cells)} cells x {people} people, {rate_hz:.0f} Hz: skeleton -> verdict",
            worst_p50, worst_p99, note)  # fmt: skip


def bench_cells(
    loads: tuple[tuple[int, int], ...] = LOADS, rate_hz: float = 120.0, seconds: float = 5.0
) -> list[Row]:
    """One row per load (worst cell's latency p50 / p99 in us), then the largest passing."""
    from sara_app.bus.session import Bus, free_port
    from sara_app.ops.supervisor import stop_processes
    from sara_app.processes.serve import WORKER_RT_PRIORITY, spawn_cell_process

    rows: list[Row] = []
    measured: list[tuple[int, int]] = []
    for n in sorted({n for n, _ in loads}):
        port = free_port()
        cells = [f"load{i + 1}" for i in range(n)]
        publishers: dict[str, Any] = {}
        with Bus.router(port) as hub, tempfile.TemporaryDirectory() as folder:
            rt, scenario = WORKER_RT_PRIORITY, scenario_at_dt(folder, DT_S)
            workers = [spawn_cell_process("sara_app.runtime.worker", c, scenario, port,
                                          rt_priority=rt) for c in cells]  # fmt: skip
            beats = [Heartbeat(hub, c).start() for c in cells]
            try:
                firsts = [hub.subscribe(keys.verdict_key(c)) for c in cells]
                t_end = time.monotonic() + 120
                waiting = set(range(n))
                while waiting and time.monotonic() < t_end:
                    waiting = {i for i in waiting if not firsts[i].drain().messages}
                    time.sleep(0.1)
                for f in firsts:
                    f.close()
                for people in sorted(p for m, p in loads if m == n):
                    for b in beats:
                        b.people = {f"p{k}" for k in range(people)}
                    time.sleep(0.5)
                    rows.append(_load(hub, cells, people, rate_hz, seconds, publishers))
                    measured.append((n, people))
            finally:
                for b in beats:
                    b.stop()
                stop_processes(workers)
    passing = [load for load, r in zip(measured, rows, strict=True) if r[3].endswith("PASSES")]
    best = max(passing, key=lambda load: (load[0] * load[1], load[0]), default=None)
    rows.append(("largest passing load", np.nan, np.nan,
                 f"{best[0]} cells x {best[1]} people" if best else "none"))  # fmt: skip
    return rows
