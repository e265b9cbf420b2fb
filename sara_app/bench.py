"""Benchmarks: median and p99 of the hot-path stages (``sara-app bench``)."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach


def timeit_us(fn: Callable[[], object], n: int = 2000, warmup: int = 200) -> tuple[float, float]:
    """Median and p99 of ``n`` calls, microseconds."""
    for _ in range(warmup):
        fn()
    t = np.empty(n)
    clock = time.perf_counter_ns
    for i in range(n):
        t0 = clock()
        fn()
        t[i] = clock() - t0
    return float(np.median(t) / 1e3), float(np.percentile(t, 99) / 1e3)


def _human(H: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    y = rng.normal(scale=0.3, size=(H, 15, 3)) + np.array([0.0, 0.0, 1.0])
    return y, rng.normal(scale=0.5, size=y.shape), np.full((H, 15), 0.5)


def bench_reach(n: int = 2000) -> list[tuple[str, float, float, str]]:
    """All three SaRA models: one human one horizon, 10 intervals, batches of 1, 8, 64."""
    reach = HumanReach(to_reach_params(load_param_set("seed001_table1"), "full"))
    rng = np.random.default_rng(0)
    rows = []
    one_s, one_e = np.array([0.0]), np.array([0.3])
    ten_s = np.linspace(0.0, 0.27, 10)
    ten_e = ten_s + 0.03
    for H, ts, te, label in (
        (1, one_s, one_e, "1 human, 1 interval"),
        (1, ten_s, ten_e, "1 human, 10 intervals"),
        (8, one_s, one_e, "8 humans, 1 interval"),
        (64, one_s, one_e, "64 humans, 1 interval"),
    ):
        y, v, dv = _human(H, rng)

        def all3(y=y, v=v, dv=dv, ts=ts, te=te) -> None:
            reach.pos(y, te)
            reach.vel(y, te)
            reach.acc(y, v, dv, ts, te)

        med, p99 = timeit_us(all3, n)
        rows.append((f"reach POS+VEL+ACC, {label}", med, p99, f"{med / H:.1f} us/human"))
        if H == 1 and len(te) == 1:
            for name, fn in (
                ("pos", lambda y=y, te=te: reach.pos(y, te)),
                ("vel", lambda y=y, te=te: reach.vel(y, te)),
                ("acc", lambda y=y, v=v, dv=dv, ts=ts, te=te: reach.acc(y, v, dv, ts, te)),
                ("iso13855", lambda y=y, te=te: reach.iso13855(y, te)),
            ):
                m, p = timeit_us(fn, n)
                rows.append((f"  {name} alone", m, p, ""))
    return rows


# modules with a ``bench_rows(n)`` of their own, in print order
STAGE_MODULES = (
    "sara_app.safety.bench_shield",
    "sara_app.safety.pfl",
    "sara_app.safety.pfl_shield",
    "sara_app.safety.jssa",
    "sara_app.safety.jssa_mode",
    "sara_app.bus.bench",
    "sara_app.dashboard.scene",
    "sara_app.api.bench",
    "sara_app.robot.ik",
)


def bench_latency(n: int = 200) -> list[tuple[str, float, float, str]]:
    """End to end: a skeleton published by a client -> the verdict that used it received by a
    client, through a zenoh router and a cell worker process (all on 127.0.0.1)."""
    import subprocess
    import sys

    from sara_app.bus import keys
    from sara_app.bus.messages import SkeletonMsg, VerdictMsg
    from sara_app.bus.session import Bus, free_port
    from sara_app.human.scripted import joints, standing

    port = free_port()
    lat = []
    with Bus.router(port) as hub:
        worker = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "sara_app.worker",
                "--cell",
                "bench",
                "--scenario",
                "empty_cell",
                "--port",
                str(port),
            ]  # fmt: skip
        )
        try:
            sub = hub.subscribe(keys.verdict_key("bench"), fifo=True, capacity=10000)
            pub = hub.publisher(keys.skeleton_key("bench", "p"))
            y = joints(standing((1.5, 0.0), 0.0))
            t_wait = time.monotonic() + 30
            while not sub.drain().messages and time.monotonic() < t_wait:
                time.sleep(0.05)
            for i in range(n):
                t_pub = time.time()
                pub.put(SkeletonMsg.from_arrays("full", y, seq=i, stamp_s=t_pub))
                t_end = time.monotonic() + 1.0
                got = None
                while got is None and time.monotonic() < t_end:
                    for d in sub.drain().messages:
                        m = d.msg
                        if isinstance(m, VerdictMsg) and "p" in m.skeleton_age_s:
                            if abs(m.stamp_s - m.skeleton_age_s["p"] - t_pub) < 1e-6:
                                got = d.recv_s - t_pub
                    time.sleep(0.0002)
                if got is not None:
                    lat.append(got * 1e6)
                time.sleep(0.01)
        finally:
            worker.terminate()
            worker.wait(10)
    if not lat:
        return [
            (
                "skeleton -> verdict (zenoh, worker process)",
                float("nan"),
                float("nan"),
                "no verdict received",
            )
        ]
    a = np.array(lat)
    return [
        (
            "skeleton -> verdict (zenoh, worker process)",
            float(np.median(a)),
            float(np.percentile(a, 99)),
            f"{len(a)}/{n} matched",
        )
    ]


def run(n: int = 2000) -> None:
    import importlib

    rows = bench_reach(n)
    for mod in STAGE_MODULES:
        try:
            rows += importlib.import_module(mod).bench_rows(n)
        except ModuleNotFoundError:
            continue
    rows += bench_latency(min(n, 200))
    print_rows(rows)


def print_rows(rows: list[tuple[str, float, float, str]]) -> None:
    print(f"{'stage':48s} {'median us':>10s} {'p99 us':>10s}  note")
    for name, med, p99, note in rows:
        print(f"{name:48s} {med:10.1f} {p99:10.1f}  {note}")
