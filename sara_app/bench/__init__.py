"""Benchmarks: median and p99 of the hot-path stages (``sara-app bench``), outside the library:
one module per stage (``bench_rows(n)``), the live-stack benchmarks (:mod:`.live`: the view's
load, :mod:`.sse`: the API's event streams) and the scenes they share with the tests."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach


def timeit_us(
    fn: Callable[[], object], n: int = 2000, warmup: int = 200, idle_s: float = 0.0
) -> tuple[float, float]:
    """Median and p99 of ``n`` calls, microseconds; ``idle_s``: the thread sleeps that long
    before each timed call, as a control loop does between its cycles (on this project's
    development VM a call after a 2 ms sleep costs 2-3x a call in a tight loop: caches and
    branch predictors no longer hold its code and data)."""
    for _ in range(warmup):
        fn()
    t = np.empty(n)
    clock = time.perf_counter_ns
    for i in range(n):
        if idle_s > 0.0:
            time.sleep(idle_s)
        t0 = clock()
        fn()
        t[i] = clock() - t0
    return float(np.median(t) / 1e3), float(np.percentile(t, 99) / 1e3)


def _human(H: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    y = rng.normal(scale=0.3, size=(H, 15, 3)) + np.array([0.0, 0.0, 1.0])
    return y, rng.normal(scale=0.5, size=y.shape), np.full((H, 15), 0.5)


def bench_reach(n: int = 2000) -> list[tuple[str, float, float, str]]:
    """All three SaRA models: one human one horizon, 10 intervals, batches of 1, 8, 64."""
    reach = HumanReach(to_reach_params(load_param_set("schepp2022_table1"), "full"))
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
    "sara_app.bench.shield",
    "sara_app.bench.display",
    "sara_app.bench.energy",
    "sara_app.bench.pfl",
    "sara_app.bench.people",
    "sara_app.bench.jssa",
    "sara_app.bench.jssa_mode",
    "sara_app.bench.bus",
    "sara_app.bench.scene",
    "sara_app.bench.api",
    "sara_app.bench.ik",
)


def run(n: int = 2000) -> None:
    import importlib

    rows = bench_reach(n)
    for mod in STAGE_MODULES:
        try:
            rows += importlib.import_module(mod).bench_rows(n)
        except ModuleNotFoundError:
            continue
    print_rows(rows)


def print_rows(rows: list[tuple[str, float, float, str]]) -> None:
    print(f"{'stage':48s} {'median us':>10s} {'p99 us':>10s}  note")
    for name, med, p99, note in rows:
        print(f"{name:48s} {med:10.1f} {p99:10.1f}  {note}")
