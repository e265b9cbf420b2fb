"""The worker's cycle time with the dashboard and a browser connected versus without (target:
no more than 10 % worse), measured on the live stack of ``sara-app serve``.

A Zenoh router (a process of its own), the reference controller, a cell worker and a replayer
run as in ``serve``; the worker's verdicts (one per cycle, with its own cycle time) are
collected in alternating phases: without a view, then with the viser dashboard fed at 20 Hz and
a headless Debian chromium rendering it, and so on. Phases alternate (their order rotates each
round) so that drifts of the machine's load hit all sides alike. Command delivery is the
controller's own count (its ``controller/status``): commands lost, late, expired on arrival,
and how often it braked on its own because none came in time.

The view runs in two variants: at lowered CPU priority (nice ``serve.DISPLAY_NICE``, as ``sara-app
serve`` runs its display side; the browser too, standing for an operator's browser that normally
runs on another machine) and at the worker's own priority (everything competing equally for the
cores). The replayer runs at ``serve.REPLAYER_NICE`` in every phase, as in ``serve``.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import tempfile
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import cast

import numpy as np

from sara_app.bus import keys
from sara_app.bus.messages import ControllerStatusMsg, VerdictMsg
from sara_app.bus.session import Bus, free_port
from sara_app.ops.chromium import CHROMIUM_FLAGS, chromium_environment, chromium_path, stop_chromium
from sara_app.processes.affinity import CpuPlan, placed_as_serve


def _collect(hub: Bus, cell: str, seconds: float) -> np.ndarray:
    """``(n, 3)``: cycle time (us), stamp (s) and sequence number of the verdicts received over
    ``seconds``."""
    sub = hub.subscribe(keys.verdict_key(cell), fifo=True, capacity=100_000)
    out: list[tuple[float, float, int]] = []
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        time.sleep(0.05)
        out += [
            (d.msg.cycle_time_us, d.msg.stamp_s, d.msg.seq)
            for d in sub.drain().messages
            if isinstance(d.msg, VerdictMsg)
        ]
    sub.close()
    return np.array(out, dtype=float).reshape(-1, 3)


def _controller_status(hub: Bus, cell: str, wait_s: float = 3.0) -> ControllerStatusMsg | None:
    """The controller's next status (its command-delivery counts since it started)."""
    sub = hub.subscribe(keys.controller_status_key(cell), capacity=16)
    t_end = time.monotonic() + wait_s
    try:
        while time.monotonic() < t_end:
            got = [d.msg for d in sub.drain().messages if isinstance(d.msg, ControllerStatusMsg)]
            if got:
                return got[-1]
            time.sleep(0.05)
        return None
    finally:
        sub.close()


DELIVERY_FIELDS = ("commands_received", "commands_lost", "commands_late", "commands_expired",
                   "braking_events")  # fmt: skip


def delivery_delta(
    before: ControllerStatusMsg | None, after: ControllerStatusMsg | None
) -> np.ndarray | None:
    """``(5,)`` counts between two controller statuses, in ``DELIVERY_FIELDS`` order."""
    if before is None or after is None:
        return None
    return np.array([getattr(after, f) - getattr(before, f) for f in DELIVERY_FIELDS], float)


def delivery_row(label: str, counts: list[np.ndarray | None]) -> tuple[str, float, float, str]:
    """One row of command delivery at the controller over phases: lost and expired-on-arrival
    shares (%) of the commands sent, with late ones and braking events in the note."""
    got = [c for c in counts if c is not None]
    if not got:
        return (f"commands at the controller, {label}", float("nan"), float("nan"), "no status")
    received, lost, late, expired, braked = np.sum(got, axis=0)
    sent = max(received + lost, 1.0)
    return (
        f"commands at the controller, {label}",
        100 * lost / sent,
        100 * expired / sent,
        f"% lost / expired on arrival of {int(sent)}; {100 * late / sent:.1f} % late; "
        f"braked on its own {int(braked)}x",
    )


def _missed(phases: list[np.ndarray], dt_s: float) -> tuple[int, int]:
    """Over phases of :func:`_collect`: cycles the worker did not run in time (the control
    period's slots between its first and last verdict without a verdict sequence number) and
    verdicts lost on the way (sequence numbers never received)."""
    skipped = dropped = 0
    for a in phases:
        if len(a) < 2:
            continue
        seq_span = int(a[-1, 2] - a[0, 2]) + 1
        slots = int(round((a[-1, 1] - a[0, 1]) / dt_s)) + 1
        skipped += max(slots - seq_span, 0)
        dropped += seq_span - len(a)
    return skipped, dropped


class _Display(threading.Thread):
    """The dashboard fed at 20 Hz, built and run on a thread of its own whose CPU priority is
    lowered by ``nice`` first (as ``sara-app serve`` runs its display side): viser's threads
    are started from it and inherit that priority."""

    def __init__(self, hub: Bus, cell: str, scenario: str, nice: int) -> None:
        super().__init__(daemon=True)
        self.hub, self.cell, self.scenario, self.nice = hub, cell, scenario, nice
        self.url: str | None = None
        self.ready = threading.Event()
        self.stop_event = threading.Event()

    def run(self) -> None:
        from sara_app.dashboard.bridge import CellView
        from sara_app.dashboard.viewer import Dashboard
        from sara_app.geometry.poses import pose_from_xyz_rpy
        from sara_app.processes.serve import lower_thread_priority
        from sara_app.scenario import load_scenario, scenarios_dir

        lower_thread_priority(self.nice)
        sc = load_scenario(self.scenario)
        T = pose_from_xyz_rpy(sc.robot.base_xyz_m, sc.robot.base_rpy_rad)
        dash = Dashboard(robot=sc.robot.name, T_world_base=T)
        try:
            view = CellView(self.cell, self.hub, dash, sc, scenarios_dir())
            self.url = dash.start(port=free_port())
            self.ready.set()
            while not self.stop_event.is_set():
                frame = view.poll()
                if frame is not None:
                    dash.update(frame)
                self.stop_event.wait(0.05)
        finally:
            self.ready.set()
            dash.stop()


@contextmanager
def _view(
    hub: Bus, cell: str, scenario: str, browser: str | None, nice: int,
    browser_cpus: frozenset[int] | None = None,
) -> Iterator[str]:  # fmt: skip
    """The dashboard (at ``nice``) and a headless browser on it (at ``nice`` too, on
    ``browser_cpus`` when given: a user's browser is not confined to the display side's CPUs)."""
    from sara_app.processes.serve import start_process

    display = _Display(hub, cell, scenario, nice)
    display.start()
    display.ready.wait(60)
    proc = None
    profile = tempfile.mkdtemp(prefix="sara-bench-chromium-")
    try:
        if display.url is None:
            raise RuntimeError("the dashboard did not start")
        if browser:
            cmd = [browser, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", display.url]
            proc = start_process(
                cmd,
                nice,
                browser_cpus,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
                env=chromium_environment(profile),
            )
        time.sleep(3.0)  # page load and first render before measuring
        yield display.url
    finally:
        display.stop_event.set()
        if proc is not None:
            stop_chromium(proc, profile)
        display.join(10)
        shutil.rmtree(profile, ignore_errors=True)  # no browser started


def _stats(a: np.ndarray) -> tuple[float, float]:
    return float(np.median(a)), float(np.percentile(a, 99))


def bench_view_load(
    scenario: str = "punches", phase_s: float = 6.0, rounds: int = 2, pin_cpus: bool = True
) -> list[tuple[str, float, float, str]]:
    """Rows: worker cycle time without a view, with the dashboard + browser at lowered priority
    (as ``serve`` runs them) and at the worker's own priority, and the ratios to no view.
    ``pin_cpus``: the cell's processes and the display side on serve's CPUs (the worker on one
    of its own), the browser on every CPU."""
    every_cpu = frozenset(os.sched_getaffinity(0))  # the browser's
    with placed_as_serve(pin_cpus) as plan:  # this process is the display side
        return _view_rows(scenario, phase_s, rounds, plan, every_cpu)


def _view_rows(
    scenario: str, phase_s: float, rounds: int, plan: CpuPlan | None, every_cpu: frozenset[int]
) -> list[tuple[str, float, float, str]]:
    from sara_app.ops.supervisor import stop_processes
    from sara_app.processes.serve import (
        DISPLAY_NICE,
        connect_when_listening,
        start_cell,
        start_router,
    )
    from sara_app.scenario import load_scenario

    port = free_port()
    cell = "benchview"
    browser = chromium_path()
    phases: dict[object, list[np.ndarray]] = {"off": [], DISPLAY_NICE: [], 0: []}
    delivered: dict[object, list[np.ndarray | None]] = {k: [] for k in phases}
    order: list[object] = ["off", DISPLAY_NICE, 0]
    # as serve runs them: the router a process of its own, real-time; the controller follows
    # the worker's commands
    router = start_router(port, None if plan is None else plan.rest)
    with connect_when_listening(port, router) as hub:
        procs = [router, *start_cell(cell, scenario, port, plan)]
        try:
            _collect(hub, cell, 3.0)  # start-up
            for r in range(rounds):
                for kind in order[r % 3 :] + order[: r % 3]:  # rotate: no phase always first
                    with contextlib.ExitStack() as stack:
                        if kind != "off":
                            nice = int(cast(int, kind))
                            stack.enter_context(
                                _view(hub, cell, scenario, browser, nice, every_cpu)
                            )
                        before = _controller_status(hub, cell)
                        phases[kind].append(_collect(hub, cell, phase_s))
                        delivered[kind].append(
                            delivery_delta(before, _controller_status(hub, cell))
                        )
        finally:
            stop_processes(procs[::-1])
    data = {k: np.concatenate(v)[:, 0] if v else np.empty(0) for k, v in phases.items()}
    dt_s = load_scenario(scenario).shield.dt_s
    missed = {k: _missed(v, dt_s) for k, v in phases.items()}
    if not all(a.size for a in data.values()):
        return [("worker cycle, view on vs off", float("nan"), float("nan"), "no verdicts")]
    what = "dashboard + browser" if browser else "dashboard (NO browser found)"
    m0, p0 = _stats(data["off"])

    def cycles(k: object) -> str:
        skipped, dropped = missed[k]
        return f"{data[k].size} verdicts; {skipped} cycles late by > 1 period, {dropped} lost"

    rows = [("worker cycle, no view", m0, p0, f"{scenario}, {cycles('off')}")]
    rows.append(delivery_row("no view", delivered["off"]))
    for kind, label in ((DISPLAY_NICE, f"nice {DISPLAY_NICE} as in serve"), (0, "same priority")):
        m, p = _stats(data[kind])
        rows.append((f"worker cycle, {what}, {label}", m, p, cycles(kind)))
        rows.append(delivery_row(label, delivered[kind]))
        rows.append(
            ("  vs no view (ratio - 1)", 100 * (m / m0 - 1), 100 * (p / p0 - 1), "%, target <= 10")
        )
    return rows
