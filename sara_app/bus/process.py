"""The ``main`` of a cell process (worker, replayer): arguments, a zenoh client session, stop on
SIGINT/SIGTERM, domain errors as exit code 2, optionally a real-time scheduling class for the
loop."""

from __future__ import annotations

import argparse
import gc
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Callable
from typing import Protocol

from sara_app.bus.access import Credentials, client_auth
from sara_app.bus.io_threads import use_one_io_thread
from sara_app.bus.session import ROBOT_ENCODINGS, Bus
from sara_app.errors import SaraError
from sara_app.options import PORT, RT_PRIORITY, SECONDS
from sara_app.tethered import die_with_parent


class CellProcess(Protocol):
    stop_event: threading.Event

    def run(self, duration_s: float | None = None) -> None: ...


LOG_LEVEL_ENV = "SARA_LOG_LEVEL"
"""The log level of a cell's processes (``sara-app serve --log-level`` sets it for its
children): ``info`` says what a user needs, ``debug`` adds implementation details."""


def configure_logging(name: str) -> None:
    """Log lines ``<time> <name> <message>`` at the level of ``SARA_LOG_LEVEL`` (info when unset
    or unknown)."""
    number = logging.getLevelName(os.environ.get(LOG_LEVEL_ENV, "info").upper())
    if not isinstance(number, int):
        number = logging.INFO
    logging.basicConfig(level=number, format=f"%(asctime)s {name} %(message)s")


def process_parser(name: str, description: str, *, state: bool = False) -> argparse.ArgumentParser:
    """The options of a cell process (:func:`process_main`); ``state``: with ``--state-dir`` and
    ``--audit``. Numbers are checked where they are given (:mod:`sara_app.options`)."""
    ap = argparse.ArgumentParser(prog=f"sara_app.{name}", description=description)
    ap.add_argument("--cell", default="cell1")
    ap.add_argument("--scenario", default="standing_beside_path")
    ap.add_argument("--port", type=PORT, default=7447, help="zenoh router port")
    ap.add_argument("--router-host", default="127.0.0.1",
                    help="the router's address (another machine: docs/deployment.md)")  # fmt: skip
    ap.add_argument("--duration", type=SECONDS, default=None, help="s (default: until stopped)")
    ap.add_argument(
        "--rt-priority",
        type=RT_PRIORITY,
        default=0,
        help="run the loop thread under SCHED_FIFO at this priority (1-99; 0: normal scheduling)",
    )
    ap.add_argument(
        "--die-with-parent",
        action="store_true",
        help=(
            "end when the parent process ends, asked after this module's imports (serve asks "
            "before them: it starts its children through python -m sara_app.tethered)"
        ),
    )
    ap.add_argument(
        "--robot-encoding",
        choices=ROBOT_ENCODINGS,
        default="compact",
        help="how it publishes robot states and commands (compact: the binary records of the "
        "contract; json: for a peer that reads JSON only); it reads both",
    )
    ap.add_argument("--zenoh-user", default=None, help="this process's role on the bus")
    ap.add_argument(
        "--zenoh-credentials", default=None, help="the credentials file (user:password lines)"
    )
    if state:
        ap.add_argument("--state-dir", default=None, help="keep the cell's edits in this folder")
        ap.add_argument(
            "--audit",
            default=None,
            help="record every edit, retirement and re-plan answered in this audit log (SQLite)",
        )
    return ap


def process_main(
    name: str,
    description: str,
    factory: Callable[..., CellProcess],
    argv: list[str] | None = None,
    *,
    state: bool = False,
    timestamped: bool = False,
    one_io_thread: bool = False,
) -> int:
    """Run ``factory(cell, scenario, bus)`` (with ``state_dir=``, ``origin=`` and ``audit=``
    keywords when ``state``: the folder of ``--state-dir``, the ``--scenario`` argument and the
    audit log of ``--audit``); ``timestamped``: its messages carry zenoh's publication
    timestamp (:func:`~sara_app.bus.session.client_config`); ``one_io_thread``: zenoh's I/O on
    one thread, for a process without FIFO subscriptions (:mod:`~sara_app.bus.io_threads`)."""
    ap = process_parser(name, description, state=state)
    args = ap.parse_args(argv)
    if args.die_with_parent:
        die_with_parent()
    configure_logging(name)
    try:
        # here, not at the top: the router imports this module and needs no scenario (0.5 s)
        from sara_app.scenario import load_scenario

        sc = load_scenario(args.scenario)
        auth = None
        if args.zenoh_user is not None or args.zenoh_credentials is not None:
            if not (args.zenoh_user and args.zenoh_credentials):
                raise SaraError("--zenoh-user and --zenoh-credentials go together")
            auth = client_auth(args.zenoh_user, Credentials(args.zenoh_credentials))
        bus, rt = realtime_session(
            args.rt_priority,
            name,
            lambda: Bus.client(
                args.port,
                args.router_host,
                auth=auth,
                robot_encoding=args.robot_encoding,
                timestamping=timestamped,
            ),  # fmt: skip
            one_io_thread=one_io_thread,
        )
        with bus:  # building the cell (seconds of kernel loading) at normal priority
            kw = (
                {"state_dir": args.state_dir, "origin": args.scenario, "audit": args.audit}
                if state else {}
            )  # fmt: skip
            proc = factory(args.cell, sc, bus, **kw)
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: proc.stop_event.set())
            freeze_heap(name)
            if rt:
                set_realtime(args.rt_priority, name)
            proc.run(args.duration)
    except SaraError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


def freeze_heap(name: str = "process") -> int:
    """Collect once, then move every object alive into the collector's permanent generation
    (``gc.freeze``): what a process built before its loop (the cell, numba's and pinocchio's
    objects: ~190 000) is never traversed again. Without it a full collection, which Python
    starts on its own after enough allocations, takes ~60 ms on this machine and stalls the
    loop (commands expired at the controller, the robot braked). Frozen objects are still
    freed by reference counting; only cyclic garbage among them stays. Returns the number
    frozen."""
    gc.collect()
    gc.freeze()
    n = gc.get_freeze_count()
    logging.getLogger(f"sara_app.{name}").debug("%d objects frozen before the loop", n)
    return n


def realtime_session(
    priority: int, name: str, open_bus: Callable[[], Bus], *, one_io_thread: bool = False
) -> tuple[Bus, bool]:
    """``open_bus()`` with the calling thread under ``SCHED_FIFO`` at ``priority`` (0: normal
    scheduling), so that zenoh's I/O threads, which a process starts once, with its first
    session, inherit the class: received and sent messages then do not wait behind a browser or
    other normal jobs. ``one_io_thread``: those threads are one, for a process without FIFO
    subscriptions (:mod:`~sara_app.bus.io_threads`). The calling thread is back at normal
    scheduling when this returns or raises. Returns the session and whether the class was
    taken (:func:`set_realtime`)."""
    if one_io_thread:
        use_one_io_thread()
    rt = bool(priority) and set_realtime(priority, name, "session threads")
    try:
        return open_bus(), rt
    finally:
        if rt:
            set_normal()


def set_normal() -> None:
    """Put the calling thread back under normal scheduling (threads it started keep theirs)."""
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (AttributeError, OSError):
        pass


def set_realtime(priority: int, name: str = "process", what: str = "loop thread") -> bool:
    """Put the calling thread under ``SCHED_FIFO`` at ``priority`` (1-99): it then runs as soon
    as it wakes, ahead of every normally scheduled thread (display, browser, other jobs); threads
    it starts afterwards inherit the class (those started before keep theirs). Linux keeps 5 %
    of each second for normal threads (``sched_rt_runtime_us``), so a runaway loop cannot lock
    the machine. Returns False, with a warning, where it is not permitted (no CAP_SYS_NICE, other
    systems): the loop then runs at normal priority."""
    log = logging.getLogger(f"sara_app.{name}")
    lo = os.sched_get_priority_min(os.SCHED_FIFO) if hasattr(os, "SCHED_FIFO") else 1
    hi = os.sched_get_priority_max(os.SCHED_FIFO) if hasattr(os, "SCHED_FIFO") else 99
    if not lo <= priority <= hi:
        raise SaraError(f"rt priority = {priority}; expected {lo} to {hi} (0: off)")
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError) as e:
        log.warning("real-time scheduling not permitted (%s): the loop runs at normal priority", e)
        return False
    log.debug("%s under SCHED_FIFO, priority %d", what, priority)
    return True


class SummarisedWarning:
    """A warning that can repeat at the control rate, logged once when it first happens and
    then as one line per ``interval_s`` with its count ("commands expired 2048 times in the last
    60 s"), never a line each. ``clock``: seconds (monotonic by default)."""

    def __init__(
        self,
        log: logging.Logger,
        what: str,
        interval_s: float = 60.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.log, self.what, self.interval_s, self.clock = log, what, interval_s, clock
        self.total = 0
        self._window_start: float | None = None
        self._in_window = 0

    def __call__(self, detail: str = "") -> None:
        """One occurrence (``detail``: what this one was)."""
        now = self.clock()
        self.total += 1
        if self._window_start is None:  # the first: said at once
            self.log.warning("%s%s", self.what, f": {detail}" if detail else "")
            self._window_start, self._in_window = now, 0
            return
        self._in_window += 1
        if now - self._window_start >= self.interval_s:
            self.log.warning(
                "%s %d times in the last %.0f s (%d in all)%s", self.what, self._in_window,
                now - self._window_start, self.total, f"; the last: {detail}" if detail else "",
            )  # fmt: skip
            self._window_start, self._in_window = now, 0
