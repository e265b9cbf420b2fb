"""The worker's cycle time with the dashboard and a browser connected versus without (issue 4:
no more than 10 % worse), measured on the live stack of ``sara-app serve``.

A Zenoh router, a cell worker and a replayer run as in ``serve``; the worker's verdicts (one per
cycle, with its own cycle time) are collected in alternating phases: without a view, then with
the viser dashboard fed at 20 Hz and a headless Debian chromium rendering it, and so on. Phases
alternate so that drifts of the machine's load hit both sides alike.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np

from sara_app.bus import keys
from sara_app.bus.messages import VerdictMsg
from sara_app.bus.session import Bus, free_port

CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--window-size=960,600",
)


def chromium_path() -> str | None:
    """Debian's chromium, if installed (never downloaded)."""
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    return "/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else None


def _collect(hub: Bus, cell: str, seconds: float) -> np.ndarray:
    """Cycle times (us) of the verdicts received over ``seconds``."""
    sub = hub.subscribe(keys.verdict_key(cell), fifo=True, capacity=100_000)
    out: list[float] = []
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        time.sleep(0.05)
        out += [d.msg.cycle_time_us for d in sub.drain().messages if isinstance(d.msg, VerdictMsg)]
    sub.close()
    return np.array(out)


@contextmanager
def _view(hub: Bus, cell: str, scenario: str, browser: str | None) -> Iterator[str]:
    """The dashboard fed at 20 Hz in a thread of this process, and a browser on it."""
    from sara_app.cell import base_pose
    from sara_app.dashboard.bridge import CellView
    from sara_app.dashboard.viewer import Dashboard
    from sara_app.scenario import load_scenario, scenarios_dir

    sc = load_scenario(scenario)
    dash = Dashboard(
        robot=sc.robot.name, T_world_base=base_pose(sc.robot.base_xyz_m, sc.robot.base_rpy_rad)
    )
    view = CellView(cell, hub, dash, sc, scenarios_dir())
    url = dash.start(port=free_port())
    stop = threading.Event()

    def feed() -> None:
        while not stop.is_set():
            frame = view.poll()
            if frame is not None:
                dash.update(frame)
            stop.wait(0.05)

    th = threading.Thread(target=feed, daemon=True)
    th.start()
    proc = None
    profile = tempfile.mkdtemp(prefix="sara-bench-chromium-")
    if browser:
        proc = subprocess.Popen(
            [browser, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", url],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    try:
        time.sleep(3.0)  # page load and first render before measuring
        yield url
    finally:
        stop.set()
        th.join(5)
        if proc is not None:
            proc.terminate()
            proc.wait(10)
        dash.stop()
        shutil.rmtree(profile, ignore_errors=True)


def bench_view_load(
    scenario: str = "punches", phase_s: float = 6.0, rounds: int = 2
) -> list[tuple[str, float, float, str]]:
    """Rows: worker cycle time without and with the dashboard + browser, and the ratio."""
    from sara_app.serve import _spawn, _stop

    port = free_port()
    cell = "benchview"
    browser = chromium_path()
    off: list[np.ndarray] = []
    on: list[np.ndarray] = []
    with Bus.router(port) as hub:
        procs = [
            _spawn("sara_app.worker", cell, scenario, port),
            _spawn("sara_app.replayer", cell, scenario, port),
        ]
        try:
            _collect(hub, cell, 3.0)  # start-up
            for _ in range(rounds):
                off.append(_collect(hub, cell, phase_s))
                with _view(hub, cell, scenario, browser):
                    on.append(_collect(hub, cell, phase_s))
        finally:
            _stop(procs)
    a, b = np.concatenate(off), np.concatenate(on)
    if not (a.size and b.size):
        return [("worker cycle, view on vs off", float("nan"), float("nan"), "no verdicts")]
    note = "browser" if browser else "NO browser found: dashboard only"
    rows = [
        ("worker cycle, no view", float(np.median(a)), float(np.percentile(a, 99)), scenario),
        (
            "worker cycle, dashboard + " + ("browser" if browser else "no browser"),
            float(np.median(b)),
            float(np.percentile(b, 99)),
            note,
        ),
    ]
    r50 = np.median(b) / np.median(a) - 1.0
    r99 = np.percentile(b, 99) / np.percentile(a, 99) - 1.0
    rows.append(("  view on vs off (ratio - 1)", 100 * r50, 100 * r99, "in %, target <= 10 %"))
    return rows
