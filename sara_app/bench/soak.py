"""``sara-app soak``: the default cell under load for a long time, optionally under faults.

The cell's processes are started and supervised as ``serve`` starts them (router, controller,
worker, replayer; no dashboard), with credentials and saved state in a folder of their own.
Over the run it samples, every ``sample_s``: the control rate (verdicts received per second),
the verdict latency as the age of the newest skeleton at the decision (the verdicts report it:
sensor delay, the tracker's period and every transport and scheduling delay on the way),
the controller's own delivery counts (commands lost, late, expired; braking events) and, for
every process, its resident memory and open file descriptors (``/proc``). The result is a table
(median and extremes per quantity, growth over the run as a least-squares slope per hour) and a
PNG of every series over time.

``--chaos``: every ``chaos_every_s`` seconds a random cell process (router, worker, controller,
replayer) is killed (SIGKILL) or stopped for a while (SIGSTOP, then SIGCONT). The supervisor
restarts what died, as under ``serve``. Checked from what the controller executed, not from
logs: every robot state the controller publishes lies on a command the worker sent (its
commanded segment or its verified stop, within the tracking tolerance), so the robot never moved
on something that was not verified; after the run no process of the cell is left; and after
every fault the cell recovers (a verdict other than ``fault`` again after the fault ended: a
stopped process continued, a killed one restarted), recovery times as a distribution, with the
reasons of the fault verdicts in between.
"""

from __future__ import annotations

import bisect
import json
import os
import random
import re
import shutil
import signal
import statistics
import sys
import tempfile
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from sara_app.bus import keys
from sara_app.bus.messages import (
    ControllerStatusMsg,
    RobotCommandMsg,
    RobotStateMsg,
    VerdictMsg,
)

CHAOS_TARGETS = ("router", "worker", "controller", "replayer")
STOP_S = (0.2, 2.0)
"""How long a SIGSTOP lasts before its SIGCONT (uniform)."""
CHECK_DELAY_S = 1.0
"""How long after its arrival a robot state is checked (see ``_loop``)."""
MAX_REASONS = 16
"""Distinct reasons of fault verdicts kept per fault (``Event.faults_after``)."""
ON_PATH_TOL_RAD = 0.005
"""An executed state farther than this (per joint) from every command's path is a violation:
the scenario's tracking tolerance, within which the worker accepts the robot's state."""


@dataclass
class Event:
    t_s: float
    target: str
    action: str
    end_s: float
    """When the fault ended: a stopped process continued; a killed one was restarted by the
    supervisor (until then the kill's time, and ``restarted_from`` is set)."""
    recovered_s: float | None = None
    restarted_from: int | None = None
    """A killed process not restarted yet: its child's restart count at the kill."""
    faults_after: dict[str, int] = field(default_factory=dict)
    """The fault verdicts' reasons since the fault ended, until the cell recovered (numbers
    in them written ``#`` so that one reason counts once; at most ``MAX_REASONS``): why it
    took that long, or never recovered."""


@dataclass
class Sample:
    t_s: float
    rate_hz: float
    latency_ms: tuple[float, float]  # median, p99
    controller: dict[str, int]
    rss_mb: dict[str, float]
    fds: dict[str, int]
    loop_ms: float = 0.0
    """The observer's longest time between two passes through its loop (10 ms when it keeps
    up)."""


@dataclass
class SoakResult:
    duration_s: float
    chaos: bool
    samples: list[Sample] = field(default_factory=list)
    events: list[Event] = field(default_factory=list)
    states_checked: int = 0
    off_path: list[tuple[float, float]] = field(default_factory=list)
    """``(time, distance rad)`` of executed states on no command's path."""
    orphans: list[int] = field(default_factory=list)
    commands: int = 0


def _proc_stats(pid: int) -> tuple[float, int]:
    """Resident memory (MB) and open file descriptors of a process (nan, -1 when gone)."""
    try:
        rss_kb = next(
            int(ln.split()[1])
            for ln in Path(f"/proc/{pid}/status").read_text().splitlines()
            if ln.startswith("VmRSS:")
        )
        return rss_kb / 1024.0, len(os.listdir(f"/proc/{pid}/fd"))
    except (OSError, StopIteration, ValueError):
        return float("nan"), -1


class PathCheck:
    """Executed states against the commands' paths: each command's set point, the straight
    segment to it from the previous command's set point, and its verified stop (a polyline).
    The newest commands stamped before a state are tried first, however old (the controller
    follows the newest one it received, or the stop of the last one), then every command of
    the last ``WINDOW_S``."""

    WINDOW_S = 3.0
    KEEP_S = 30.0  # commands kept: states are checked up to CHECK_DELAY_S late, or later
    NEWEST = 8

    def __init__(self) -> None:
        self.stamps: list[float] = []
        self.paths: list[np.ndarray] = []  # (F, n) points of each command's path
        self._last_q: np.ndarray | None = None
        self.first_s = np.inf  # the first command's stamp: before it nothing was commanded

    def command(self, c: RobotCommandMsg) -> None:
        q = np.asarray(c.q, float)
        pts = [q] + [np.asarray(x, float) for x in c.failsafe_q]
        if self._last_q is not None and len(self._last_q) == len(q):
            pts = [self._last_q, *pts]
        self._last_q = q
        self.first_s = min(self.first_s, c.stamp_s)
        self.stamps.append(c.stamp_s)
        self.paths.append(np.array(pts))
        if len(self.stamps) > 4096 and self.stamps[0] < c.stamp_s - self.KEEP_S:
            k = bisect.bisect_left(self.stamps, c.stamp_s - self.KEEP_S)
            del self.stamps[:k], self.paths[:k]

    @staticmethod
    def _to_path(pts: np.ndarray, q: np.ndarray) -> float:
        if pts.shape[1] != len(q):
            return np.inf
        if len(pts) == 1:
            return float(np.abs(pts[0] - q).max())
        a, ab = pts[:-1], pts[1:] - pts[:-1]
        w = np.clip(((q - a) * ab).sum(1) / np.maximum((ab * ab).sum(1), 1e-300), 0.0, 1.0)
        return float(np.abs(a + w[:, None] * ab - q).max(axis=1).min())

    def distance(self, t_s: float, q: np.ndarray) -> float:
        """The smallest max-norm distance (rad) from ``q`` to the path of a command sent before
        ``t_s`` (within ``WINDOW_S``)."""
        hi = bisect.bisect_right(self.stamps, t_s + 0.05)
        # the newest commands before the state however old: while the router was down the
        # controller braked along the stop of the last one it had (and no state reached here)
        lo = min(bisect.bisect_left(self.stamps, t_s - self.WINDOW_S), max(hi - self.NEWEST, 0))
        best = np.inf
        order = list(range(hi - 1, max(lo, hi - self.NEWEST) - 1, -1))
        order += list(range(max(lo, hi - self.NEWEST) - 1, lo - 1, -1))
        for i in order:
            best = min(best, self._to_path(self.paths[i], q))
            if best <= ON_PATH_TOL_RAD:
                break
        return best


def run_soak(
    duration_s: float,
    *,
    chaos: bool = False,
    chaos_every_s: float = 5.0,
    sample_s: float | None = None,
    scenario: str | None = None,
    seed: int = 0,
    progress: bool = True,
) -> SoakResult:
    """Run the default cell (or ``scenario``) for ``duration_s``; see the module notes."""
    from sara_app.bus.access import Credentials, client_auth
    from sara_app.bus.session import free_port
    from sara_app.ops.supervisor import Child, Supervisor
    from sara_app.processes.serve import (
        DEFAULT_SCENARIO,
        ROUTER,
        WORKER_RT_PRIORITY,
        _cell_children,
        _connect,
        start_process,
    )
    from sara_app.tethered import command as tethered

    rng = random.Random(seed)
    sample_s = sample_s or max(1.0, duration_s / 120.0)
    data = Path(tempfile.mkdtemp(prefix="sara_soak_"))
    data_before = os.environ.get("SARA_APP_DATA")
    os.environ["SARA_APP_DATA"] = str(data)  # credentials and saved state of this run only
    cell, port = "cell1", free_port()
    creds = Credentials.create(data / "zenoh_credentials.txt")
    router_cmd = tethered(ROUTER, "--port", str(port), "--cell", cell, "--credentials",
                          str(creds.path), "--rt-priority", str(WORKER_RT_PRIORITY))  # fmt: skip

    children = [Child("router", lambda: start_process(router_cmd))]
    children += _cell_children(cell, scenario or DEFAULT_SCENARIO, False, port, creds, False)
    sup = Supervisor(children, "worker")
    res = SoakResult(duration_s, chaos)
    check = PathCheck()
    all_pids: set[int] = set()
    try:
        sup.start(("router",))
        with _connect(port, client_auth("editor", creds), sup) as bus:
            sup.start()
            subs = {
                "verdict": bus.subscribe(keys.verdict_key(cell), fifo=True, capacity=200000),
                "command": bus.subscribe(keys.robot_command_key(cell), fifo=True, capacity=200000),
                "state": bus.subscribe(keys.robot_state_key(cell), fifo=True, capacity=200000),
                "ctl": bus.subscribe(keys.controller_status_key(cell), fifo=True),
            }
            _loop(res, sup, subs, check, all_pids, duration_s, sample_s, chaos, chaos_every_s,
                  rng, progress)  # fmt: skip
    finally:
        sup.stop()
        for c in children:
            if c.proc is not None:
                all_pids.add(c.proc.pid)
        time.sleep(0.5)
        res.orphans = sorted(p for p in all_pids if _alive(p))
        # the run's bus password file and saved state go with it (every run left its folder)
        shutil.rmtree(data, ignore_errors=True)
        if data_before is None:
            os.environ.pop("SARA_APP_DATA", None)
        else:
            os.environ["SARA_APP_DATA"] = data_before
    return res


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except OSError:
        return False
    status = Path(f"/proc/{pid}/status")
    try:  # a zombie is gone (its parent has not reaped it yet)
        return "zombie" not in status.read_text().split("State:")[1].splitlines()[0]
    except (OSError, IndexError):
        return False


def _loop(
    res: SoakResult, sup: Any, subs: dict[str, Any], check: PathCheck, all_pids: set[int],
    duration_s: float, sample_s: float, chaos: bool, chaos_every_s: float,
    rng: random.Random, progress: bool,
) -> None:  # fmt: skip
    t_start = time.time()
    warm_until = t_start + 120.0
    while time.time() < warm_until:  # the worker builds its cell (kernels compiled once)
        sup.poll(time.monotonic(), None)
        if any(isinstance(d.msg, VerdictMsg) for d in subs["verdict"].drain().messages):
            break
        time.sleep(0.1)
    t0 = time.time()
    next_sample, next_chaos = t0 + sample_s, t0 + chaos_every_s
    last_sample, loop_max = t0, 0.0  # the observer's own longest pass (it must keep up)
    t_pass = t0
    window: list[float] = []  # skeleton ages of the verdicts since the last sample
    n_window = 0
    last_verdict = last_ctl = time.monotonic()
    ctl_banked: dict[str, int] = {}
    ctl_last: dict[str, int] = {}
    stopped: list[tuple[float, Any, Event]] = []
    q_prev: np.ndarray | None = None
    state_seq = -1
    pending: deque[tuple[float, RobotStateMsg]] = deque()
    while (now := time.time()) < t0 + duration_s:
        loop_max, t_pass = max(loop_max, now - t_pass), now
        for d in subs["command"].drain().messages:
            if isinstance(d.msg, RobotCommandMsg):
                check.command(d.msg)
                res.commands += 1
        for d in subs["state"].drain().messages:
            if isinstance(d.msg, RobotStateMsg):
                pending.append((now, d.msg))
        # A state is judged CHECK_DELAY_S after it arrived: the command it followed travels on
        # another key from another process and may reach this observer later (after a router
        # stall the router flushes its queues in any order).
        while pending and pending[0][0] < now - CHECK_DELAY_S:
            msg = pending.popleft()[1]
            q = np.asarray(msg.q, float)
            still = q_prev is not None and q.shape == q_prev.shape and (q == q_prev).all()
            # a controller that (re)started publishes where its simulated robot starts
            fresh = msg.seq < state_seq or msg.stamp_s < check.first_s
            q_prev, state_seq = q, msg.seq
            res.states_checked += 1
            if still or fresh:  # no motion executed
                continue
            dist = check.distance(msg.stamp_s, q)
            if dist > ON_PATH_TOL_RAD:
                res.off_path.append((msg.stamp_s - t0, dist))
                if len(res.off_path) <= 10:  # the first few, as they happen
                    last = res.events[-1].__dict__ if res.events else None
                    print(f"\noff path at {msg.stamp_s - t0:.3f} s by {dist:.4f} rad; "
                          f"last fault {last}", file=sys.stderr)  # fmt: skip
        for d in subs["verdict"].drain().messages:
            if isinstance(d.msg, VerdictMsg):
                window += d.msg.skeleton_age_s.values()
                n_window += 1
                last_verdict = time.monotonic()
                for ev in res.events:
                    if ev.recovered_s is None and ev.restarted_from is None:
                        if d.msg.stamp_s > ev.end_s:
                            _after(ev, d.msg)
        for d in subs["ctl"].drain().messages:
            if isinstance(d.msg, ControllerStatusMsg):
                last_ctl = time.monotonic()
                counts = _ctl_counts(d.msg)
                if ctl_last and counts["commands_received"] < ctl_last["commands_received"]:
                    for k, v in ctl_last.items():  # a restarted controller counts from 0
                        ctl_banked[k] = ctl_banked.get(k, 0) + v
                ctl_last = counts
        for c in sup.children:
            if c.proc is not None:
                all_pids.add(c.proc.pid)
        _restarted(res.events, sup, now)
        mono = time.monotonic()  # as serve: a verdict counts once worker and router run
        sup.poll(mono, sup.hang_age(mono, last_verdict), last_ctl > last_verdict)
        for item in list(stopped):
            if now >= item[0]:
                _signal(item[1], signal.SIGCONT)
                stopped.remove(item)
        if chaos and now >= next_chaos:
            next_chaos += chaos_every_s
            res.events.append(_strike(sup, rng, now - t0, stopped, t0))
        if now >= next_sample:
            next_sample += sample_s
            total = {k: ctl_banked.get(k, 0) + v for k, v in ctl_last.items()}
            span = now - last_sample
            res.samples.append(_sample(now - t0, window, n_window, span, total, sup))
            res.samples[-1].loop_ms = 1e3 * loop_max
            window, n_window, last_sample, loop_max = [], 0, now, 0.0
            if progress:
                s = res.samples[-1]
                print(f"\r{now - t0:7.0f} s  {s.rate_hz:6.0f} verdicts/s  "
                      f"skeleton age p99 {s.latency_ms[1]:5.1f} ms  faults {len(res.events)}",
                      end="", file=sys.stderr, flush=True)  # fmt: skip
        time.sleep(0.01)
    for _, child, _ in stopped:
        _signal(child, signal.SIGCONT)
    if progress:
        print(file=sys.stderr)


_DIGITS = re.compile(r"\d+(\.\d+)?")


def _after(ev: Event, v: VerdictMsg) -> None:
    """A verdict after ``ev`` ended and before the cell recovered from it."""
    if v.mode != "fault":
        ev.recovered_s = v.stamp_s - ev.end_s
        return
    for why in v.faults:
        key = _DIGITS.sub("#", why)
        if key in ev.faults_after or len(ev.faults_after) < MAX_REASONS:
            ev.faults_after[key] = ev.faults_after.get(key, 0) + 1


def _restarted(events: list[Event], sup: Any, now_s: float) -> None:
    """A killed process's fault ends when the supervisor has restarted it: until then the
    cell may still answer as if it ran (a controller killed a moment ago leaves a robot state
    younger than the timeout, and a verdict other than ``fault`` then is no recovery)."""
    for ev in events:
        if ev.restarted_from is not None:
            child = next(c for c in sup.children if c.name == ev.target)
            if child.restarts > ev.restarted_from:
                ev.end_s, ev.restarted_from = now_s, None


def _ctl_counts(m: ControllerStatusMsg) -> dict[str, int]:
    return {k: int(getattr(m, k)) for k in ("commands_received", "commands_lost", "commands_late",
                                            "commands_expired", "braking_events")}  # fmt: skip


def _signal(child: Any, sig: int) -> None:
    try:
        if child.proc is not None and child.proc.poll() is None:
            child.proc.send_signal(sig)
    except OSError:
        pass


def _strike(
    sup: Any, rng: random.Random, t_s: float, stopped: list[tuple[float, Any, Event]], t0: float
) -> Event:
    """Kill or stop one random cell process (the cell's clock: wall time)."""
    name = rng.choice(CHAOS_TARGETS)
    child = next(c for c in sup.children if c.name == name)
    now = time.time()
    if rng.random() < 0.5:
        _signal(child, signal.SIGKILL)
        return Event(t_s, name, "kill -9", now, restarted_from=child.restarts)
    hold = rng.uniform(*STOP_S)
    _signal(child, signal.SIGSTOP)
    ev = Event(t_s, name, f"stop {hold:.1f} s", now + hold)
    stopped.append((now + hold, child, ev))
    return ev


def _sample(
    t_s: float, window: list[float], n: int, span_s: float, ctl: dict[str, int], sup: Any
) -> Sample:
    ages = sorted(window)
    lat = (
        (1e3 * statistics.median(ages), 1e3 * ages[min(len(ages) - 1, int(0.99 * len(ages)))])
        if ages
        else (float("nan"), float("nan"))
    )
    rss, fds = {}, {}
    for c in sup.children:
        if c.proc is not None:
            rss[c.name], fds[c.name] = _proc_stats(c.proc.pid)
    me = _proc_stats(os.getpid())
    rss["soak"], fds["soak"] = me
    return Sample(t_s, n / span_s, lat, dict(ctl), rss, fds)


# -- report ---------------------------------------------------------------------------------------


def slope_per_h(t_s: list[float], y: list[float]) -> float:
    """Least-squares slope of ``y`` over ``t_s`` (s), per hour (nan with < 3 finite points)."""
    t, v = np.asarray(t_s, float), np.asarray(y, float)
    ok = np.isfinite(v)
    if ok.sum() < 3:
        return float("nan")
    return float(np.polyfit(t[ok], v[ok], 1)[0] * 3600.0)


def table(res: SoakResult) -> list[str]:
    """The result as Markdown lines."""
    S = res.samples
    t = [s.t_s for s in S]
    out = [
        f"soak {res.duration_s:.0f} s{' with chaos' if res.chaos else ''}: {len(S)} samples, "
        f"{res.commands} commands, {res.states_checked} executed states checked",
        "",
        "| quantity | median | min | max | slope per hour |",
        "|---|---|---|---|---|",
    ]

    def row(name: str, ys: list[float], fmt: str = "{:.1f}") -> None:
        f = [y for y in ys if np.isfinite(y)]
        if not f:
            return
        cells = [fmt.format(statistics.median(f)), fmt.format(min(f)), fmt.format(max(f))]
        out.append(f"| {name} | " + " | ".join(cells) + f" | {slope_per_h(t, ys):+.2f} |")

    row("control rate (verdicts/s)", [s.rate_hz for s in S])
    row("observer's longest pass (ms)", [s.loop_ms for s in S])
    row("skeleton age at the decision, median (ms)", [s.latency_ms[0] for s in S], "{:.2f}")
    row("skeleton age at the decision, p99 (ms)", [s.latency_ms[1] for s in S], "{:.2f}")
    for k in ("commands_lost", "commands_late", "commands_expired", "braking_events"):
        row(f"controller {k} (total)", [float(s.controller.get(k, np.nan)) for s in S], "{:.0f}")
    names = sorted({n for s in S for n in s.rss_mb})
    for n in names:
        row(f"RSS {n} (MB)", [s.rss_mb.get(n, np.nan) for s in S])
    for n in names:
        row(f"open fds {n}", [float(s.fds.get(n, -1)) if s.fds.get(n, -1) >= 0 else np.nan
                              for s in S], "{:.0f}")  # fmt: skip
    if res.chaos:
        rec = [e.recovered_s for e in res.events if e.recovered_s is not None]
        out += ["", f"faults injected: {len(res.events)}; recovered: {len(rec)}"]
        if rec:
            q = np.percentile(rec, [0, 50, 90, 100])
            out.append(f"recovery (s): min {q[0]:.2f}, median {q[1]:.2f}, p90 {q[2]:.2f}, "
                       f"max {q[3]:.2f}")  # fmt: skip
        by: dict[str, list[float]] = {}
        for e in res.events:
            if e.recovered_s is not None:
                by.setdefault(f"{e.target} {e.action.split()[0]}", []).append(e.recovered_s)
        for k, v in sorted(by.items()):
            out.append(f"- {k}: {len(v)} times, median {statistics.median(v):.2f} s, "
                       f"max {max(v):.2f} s")  # fmt: skip
        for e in res.events:
            if e.recovered_s is None:
                out.append(f"- not recovered from {e.target} {e.action} at {e.t_s:.1f} s: "
                           + why_faulted(e))  # fmt: skip
    out.append(f"executed states off every verified command's path: {len(res.off_path)}")
    out.append(f"processes left after the run: {len(res.orphans)}")
    return out


def why_faulted(ev: Event, top: int = 3) -> str:
    """The most frequent reasons of the fault verdicts after ``ev``, with their counts."""
    most = sorted(ev.faults_after.items(), key=lambda kv: -kv[1])[:top]
    return "; ".join(f"{n} x {why!r}" for why, n in most) or "no verdict since"


def plot(res: SoakResult, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    S = res.samples
    t = np.array([s.t_s for s in S]) / 60.0
    fig, ax = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    ax[0].plot(t, [s.rate_hz for s in S])
    ax[0].set_ylabel("verdicts / s")
    ax[1].plot(t, [s.latency_ms[0] for s in S], label="median")
    ax[1].plot(t, [s.latency_ms[1] for s in S], label="p99")
    ax[1].set_ylabel("skeleton age at decision (ms)")
    ax[1].legend()
    for n in sorted({n for s in S for n in s.rss_mb}):
        ax[2].plot(t, [s.rss_mb.get(n, np.nan) for s in S], label=n)
        ax[3].plot(t, [s.fds.get(n, np.nan) for s in S], label=n)
    ax[2].set_ylabel("RSS (MB)")
    ax[2].legend(fontsize=7)
    ax[3].set_ylabel("open fds")
    ax[3].set_xlabel("minutes")
    for e in res.events:
        for a in ax:
            a.axvline(e.t_s / 60.0, color="red", alpha=0.15, lw=0.8)
    fig.suptitle(f"sara-app soak, {res.duration_s / 60:.1f} min" + (", chaos" if res.chaos else ""))
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def write(res: SoakResult, out: Path) -> list[str]:
    """``soak.md``, ``soak.json`` and ``soak.png`` in ``out``; returns the table lines."""
    out.mkdir(parents=True, exist_ok=True)
    lines = table(res)
    (out / "soak.md").write_text("\n".join(lines) + "\n")
    doc = {
        "duration_s": res.duration_s,
        "chaos": res.chaos,
        "samples": [s.__dict__ for s in res.samples],
        "events": [e.__dict__ for e in res.events],
        "states_checked": res.states_checked,
        "off_path": res.off_path,
        "orphans": res.orphans,
        "commands": res.commands,
    }
    (out / "soak.json").write_text(json.dumps(doc, indent=1, default=float))
    plot(res, out / "soak.png")
    return lines
