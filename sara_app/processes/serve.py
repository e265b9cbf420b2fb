"""``sara-app serve``: the whole cell on one machine, no setup.

Processes: this one (the viser dashboard and the FastAPI service), the Zenoh router on 127.0.0.1
(``sara_app.bus.router``, with the cell's access control: no dashboard or API load can delay the
messages it carries), the reference robot controller (``sara_app.peers.controller``: a simulated
robot that follows the commands and brakes along their verified stop when they stop), a cell
worker and a replayer (the scenario's people, published over Zenoh as a tracker would), all
supervised (``sara_app.ops.supervisor``).
The safety loop runs in the worker process and never waits for the view. Ctrl-C stops all.

CPU priority: the safety worker comes first. Every child runs in a session of its own (a terminal's
Ctrl-C reaches only this process, which stops them in order). With Linux's session autogroups
(``/proc/sys/kernel/sched_autogroup_enabled``) the scheduler first shares the CPUs fairly between
sessions, so a worker alone in its session keeps the right to run at once when it wakes, however
busy the other sessions are; nice values rank processes within a session only. The worker's control
loop, and the zenoh I/O threads of the worker, the controller and the router (which carry the
commands and states), run under ``SCHED_FIFO`` (priority ``WORKER_RT_PRIORITY``) where the system
permits it, else at the normal priority; the replayer (a stand-in for a tracker
that normally runs elsewhere) runs at nice ``REPLAYER_NICE``, its session's autogroup too; the
display side of this process (the dashboard, the API and the threads they start) at nice
``DISPLAY_NICE``, its own zenoh I/O threads (started before) at the normal one.
"""

from __future__ import annotations

import atexit
import contextlib
import faulthandler
import ipaddress
import logging
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from sara_app.api.guard import load_tokens
from sara_app.bus.access import Credentials, client_auth
from sara_app.bus.process import LOG_LEVEL_ENV
from sara_app.bus.session import Bus
from sara_app.errors import AccessError, ParameterError, SaraError
from sara_app.geometry.poses import pose_from_xyz_rpy
from sara_app.ops.audit import default_audit_path, default_data_dir
from sara_app.ops.health import HealthLog
from sara_app.ops.idle import idle_polling
from sara_app.ops.stalls import STALL_S, Witnesses
from sara_app.ops.supervisor import Child, Supervisor
from sara_app.processes.affinity import CpuPlan, cpu_plan, pin_threads, pinned
from sara_app.processes.defaults import API_PORT, DEFAULT_SCENARIO, VIEWER_PORT, ZENOH_PORT
from sara_app.scenario import load_scenario, scenarios_dir
from sara_app.tethered import command as tethered
from sara_app.tethered import environment as tethered_environment

if TYPE_CHECKING:
    from sara_app.api.registry import Silence

log = logging.getLogger("sara_app.serve")
REPLAYER_NICE = 5
"""Nice increment of the replayer process (the worker keeps the normal priority)."""
DISPLAY_NICE = 10
"""Nice increment of the display side: dashboard, API (and a benchmark's browser)."""
WORKER_RT_PRIORITY = 10
"""SCHED_FIFO priority of the worker's control loop (normal scheduling where not permitted)."""


def niced(cmd: list[str], nice: int) -> list[str]:
    """``cmd`` run at ``nice`` more than the caller (through POSIX ``nice``; as is when the
    increment is 0 or ``nice`` is missing)."""
    tool = shutil.which("nice") if nice > 0 else None
    if nice > 0 and tool is None:
        log.warning("no 'nice' command: %s runs at normal priority", cmd[0])
    return [tool, "-n", str(int(nice)), *cmd] if tool else cmd


def start_process(
    cmd: list[str], nice: int = 0, cpus: frozenset[int] | None = None, **popen: Any
) -> subprocess.Popen[bytes]:
    """Start ``cmd`` in a session of its own, ``nice`` lower in priority than the caller, its
    session's autogroup (where the kernel has them) lowered by ``nice`` as well, on ``cpus``
    only when given (:mod:`~sara_app.processes.affinity`); it is told this process's id
    (:data:`~sara_app.tethered.PARENT_PID_ENV`, for :mod:`sara_app.tethered`)."""
    env = tethered_environment(popen.pop("env", None))
    proc = subprocess.Popen(niced(pinned(cmd, cpus), nice), start_new_session=True, env=env,
                            **popen)  # fmt: skip
    if nice > 0:  # Popen returns after exec: the child's setsid() has made its autogroup
        try:
            Path(f"/proc/{proc.pid}/autogroup").write_text(str(int(nice)))
        except OSError:
            pass  # no autogroups here (or not permitted): the nice value alone applies
    return proc


def lower_thread_priority(nice: int) -> int:
    """Raise the calling thread's nice value by ``nice`` (on Linux threads started from it
    afterwards inherit it); returns the resulting nice value (unchanged when not permitted)."""
    try:
        return os.nice(nice) if nice > 0 else os.nice(0)
    except OSError as e:
        log.warning("cannot lower the display priority: %s", e)
        return os.nice(0)


def spawn_cell_process(
    module: str,
    cell: str,
    scenario: str,
    port: int,
    nice: int = 0,
    rt_priority: int = 0,
    extra: tuple[str, ...] = (),
    cpus: frozenset[int] | None = None,
) -> subprocess.Popen[bytes]:
    """``python -m module`` for ``cell`` as serve starts it: tethered to this process from its
    first steps (:mod:`sara_app.tethered`), ``nice`` lower, at ``rt_priority``, on ``cpus``."""
    cmd = tethered(module, "--cell", cell, "--scenario", scenario, "--port", str(port),
                   "--rt-priority", str(rt_priority), *extra)  # fmt: skip
    return start_process(cmd, nice, cpus)


def start_router(port: int, cpus: frozenset[int] | None = None) -> subprocess.Popen[bytes]:
    """A router on ``port`` as serve runs it (a process of its own, real-time where permitted),
    without access control: the benchmarks' bus."""
    cmd = [sys.executable, "-m", ROUTER, "--port", str(port), "--rt-priority",
           str(WORKER_RT_PRIORITY)]  # fmt: skip
    return start_process(cmd, cpus=cpus)


def start_cell(
    cell: str, scenario: str, port: int, plan: CpuPlan | None = None,
    robot_encoding: str = "compact",
) -> list[subprocess.Popen[bytes]]:  # fmt: skip
    """The reference controller, the worker and the replayer of one cell as serve runs them
    (their priorities; their CPUs per ``plan``, the first worker's), unsupervised and without
    bus logins: the benchmarks' cell. In that order. ``robot_encoding``: how the controller
    and the worker publish states and commands (:data:`~sara_app.bus.session.ROBOT_ENCODINGS`)."""
    rt = WORKER_RT_PRIORITY
    mine, rest = (None, None) if plan is None else (plan.worker(0), plan.rest)
    enc = ("--robot-encoding", robot_encoding)
    return [
        spawn_cell_process(CONTROLLER, cell, scenario, port, 0, rt, enc, rest),
        spawn_cell_process(WORKER, cell, scenario, port, 0, rt, enc, mine),
        spawn_cell_process(REPLAYER, cell, scenario, port, REPLAYER_NICE, 0, (), rest),
    ]


def serve(
    scenario: str = DEFAULT_SCENARIO,
    *,
    cell: str = "cell1",
    zenoh_port: int = ZENOH_PORT,
    viewer_port: int = VIEWER_PORT,
    api_port: int = API_PORT,
    duration_s: float | None = None,
    frame_hz: float = 20.0,
    display_nice: int = DISPLAY_NICE,
    api_host: str = "127.0.0.1",
    require_token: bool = False,
    cells: int = 1,
    pin_cpus: bool = True,
    watch_machine: bool = False,
    idle_poll: bool = False,
) -> int:
    """Run everything until Ctrl-C (or ``duration_s``); returns the exit code. ``cells``: run
    that many cells of the scenario on the one router (:func:`cell_names`), each with its
    processes and its 3D view (ports from ``viewer_port`` on). ``pin_cpus``: each worker on a
    CPU of its own where the machine has more CPUs than cells, everything else on the others
    (:mod:`~sara_app.processes.affinity`). ``watch_machine``: a witness per CPU
    (:mod:`~sara_app.ops.stalls`) while it runs, its stalls in the health lines. ``idle_poll``:
    the idle CPUs poll while it runs (:func:`~sara_app.ops.idle.idle_polling`; where the
    request is refused, said and run as is).

    Lowers the calling thread's CPU priority by ``display_nice`` once the worker and the
    replayer are started (the dashboard and the API run on it and on threads it starts): call
    it from a process of its own, as ``sara-app serve`` does."""
    from sara_app.api.app import create_app
    from sara_app.api.registry import CellRegistry
    from sara_app.api.server import ApiServer
    from sara_app.dashboard.access import DashboardAccess
    from sara_app.dashboard.bridge import CellView
    from sara_app.dashboard.viewer import Dashboard
    from sara_app.dashboard.whatif_panel import WhatIfPanels
    from sara_app.ops.jobs import JobRunner

    folder = scenarios_dir()
    sc = load_scenario(scenario, folder)
    creds = Credentials.create(default_data_dir() / "zenoh_credentials.txt")
    names = cell_names(cell, cells)
    router_cmd = tethered(ROUTER, "--port", str(zenoh_port),
                          *(x for c in names for x in ("--cell", c)), "--credentials",
                          str(creds.path), "--rt-priority", str(WORKER_RT_PRIORITY))  # fmt: skip

    exposed = not _is_loopback(api_host)
    tokens_path = default_data_dir() / "api_tokens.json"
    tokens = load_tokens(tokens_path, create=True) if (require_token or exposed) else None
    dashes = {
        c: Dashboard(
            robot=sc.robot.name,
            T_world_base=pose_from_xyz_rpy(sc.robot.base_xyz_m, sc.robot.base_rpy_rad),
            access=DashboardAccess(tokens, c),  # the API's tokens sign browsers in
        )
        for c in names
    }
    api = None
    registry = None
    jobs: JobRunner | None = None
    whatifs: list[WhatIfPanels] = []
    hub: Bus | None = None
    sup: Supervisor | None = None
    plan = cpu_plan(len(names)) if pin_cpus else None
    rest = None if plan is None else plan.rest
    witnesses: Witnesses | None = None
    machine = contextlib.ExitStack()  # the idle request and the witnesses, released last
    try:
        if idle_poll:
            _hold_idle_polling(machine)
        if watch_machine:  # before this process is pinned: every CPU, the workers' too
            witnesses = _watch_machine(machine)
        children = [Child("router", lambda: start_process(router_cmd, cpus=rest))]
        for i, c in enumerate(names):
            cpus = (None, None) if plan is None else (plan.worker(i), plan.rest)
            children += _cell_children(c, scenario, sc.ros2.enabled, zenoh_port, creds,
                                       len(names) > 1, cpus)  # fmt: skip
        workers = {c: _child_name("worker", c, len(names) > 1) for c in names}
        sup = Supervisor(children, tuple(workers.values()))
        sup.start(("router",))
        hub = _connect(zenoh_port, client_auth("editor", creds), sup)
        sup.start()
        if plan is not None:  # the display side off the workers' CPUs (threads so far: later
            pin_threads(os.getpid(), plan.rest)  # ones inherit their creator's set)
            log.debug("workers on CPUs %s, everything else on %s", list(map(sorted, plan.workers)),
                      sorted(plan.rest))  # fmt: skip
        lower_thread_priority(display_nice)  # after the spawns: children inherit the caller's
        jobs = JobRunner()  # what-if runs and reports, for the dashboards and the API
        registry = CellRegistry(hub)  # the views follow the cells' verdicts on it
        views, urls = {}, {}
        for i, c in enumerate(names):
            view = CellView(c, hub, dashes[c], sc, folder, verdicts=registry)
            urls[c] = dashes[c].start(
                port=viewer_port + i,
                on_select_scenario=view.select,
                on_save_as=view.save_as,
                on_params_edit=view.edit,
            )
            view.refresh_panels()
            panels = view.attach_whatif(jobs)
            if panels is not None:
                whatifs.append(panels)
            views[c] = view
        registry.start()
        app = create_app(
            registry, folder, viewer_url=urls[names[0]], processes=sup.status, tokens=tokens,
            require_token=tokens is not None, hosts=() if not exposed else (api_host,),
            jobs=jobs, viewers=urls if len(names) > 1 else None,
        )  # fmt: skip
        api = ApiServer(app, host=api_host, port=api_port)
        api_url = api.start().rstrip("/")
        _print_urls(names, scenario, urls, api_url, zenoh_port, creds.path, tokens_path, tokens)

        health = HealthLog(registry, dict.fromkeys(names, 1.0 / sc.shield.dt_s),
                           machine=witnesses)  # fmt: skip

        def supervise() -> None:
            seen = {w: registry.silence(c) for c, w in workers.items()}
            ages = {w: _silent_for(s, sup, w) for w, s in seen.items()}
            bus = {w: s is not None and s.bus_since for w, s in seen.items()}
            sup.poll(time.monotonic(), ages, bus)
            health.poll()

        frame_loop([(views[c], dashes[c]) for c in names], frame_hz, duration_s, supervise)
        return 0
    except KeyboardInterrupt:
        return 0
    finally:
        for w in whatifs:
            w.close()
        if jobs is not None:
            jobs.close()
        if sup is not None:
            sup.stop()
        if api is not None:
            api.stop()
        if registry is not None:
            registry.close()
        for d in dashes.values():
            d.stop()
        if hub is not None:
            hub.close()
        machine.close()


def _hold_idle_polling(stack: contextlib.ExitStack) -> None:
    """A CPU latency request of 0 held on ``stack`` (docs/deployment.md, "The machine"), or a
    warning why not."""
    try:
        stack.enter_context(idle_polling())
    except AccessError as e:
        log.warning("the idle CPUs are left as they are: %s", e)
        return
    log.info("the idle CPUs poll while serve runs (a CPU latency request of 0 us)")


def _watch_machine(stack: contextlib.ExitStack) -> Witnesses | None:
    """The witnesses of every CPU this process may use, stopped with ``stack``, or None (said
    why) where real-time scheduling is refused."""
    witnesses = Witnesses()
    stack.callback(witnesses.stop)
    if witnesses.refused is not None:
        log.warning("the machine is not watched: %s (a witness needs SCHED_FIFO)",
                    witnesses.refused)  # fmt: skip
        return None
    cpus = ", ".join(map(str, sorted(os.sched_getaffinity(0))))
    log.info("watching the machine: a witness on each of CPUs %s, its stalls of over %g ms "
             "in a line a minute", cpus, 1e3 * STALL_S)  # fmt: skip
    return witnesses


def cell_names(cell: str, n: int) -> list[str]:
    """``[cell]`` for one cell; for ``n`` cells ``<base>1 .. <base>n`` (``cell1`` gives
    ``cell1, cell2, ...``)."""
    if n < 1 or n > MAX_CELLS:
        raise ParameterError(f"--cells {n}; expected 1..{MAX_CELLS}")
    if n == 1:
        return [cell]
    base = cell.rstrip("0123456789") or "cell"
    return [f"{base}{i}" for i in range(1, n + 1)]


def _child_name(role: str, cell: str, several: bool) -> str:
    return f"{role}:{cell}" if several else role


def _cell_children(
    cell: str, scenario: str, ros2: bool, zenoh_port: int, creds: Credentials, several: bool,
    cpus: tuple[frozenset[int] | None, frozenset[int] | None] = (None, None),
) -> list[Child]:  # fmt: skip
    """One cell's supervised processes: the robot (the reference controller, or the ROS 2
    system through the bridge), the worker and the replayer; ``cpus``: the worker's CPUs and
    the others' (None: any)."""
    mine, rest = cpus
    rt = WORKER_RT_PRIORITY
    keep = (
        "--state-dir",
        str(default_data_dir() / "cells"),  # edits survive restarts
        "--audit",
        str(default_audit_path()),
    )  # what the worker answered, whoever asked

    def login(role: str) -> tuple[str, ...]:
        return ("--zenoh-user", role, "--zenoh-credentials", str(creds.path))

    def name(role: str) -> str:
        return _child_name(role, cell, several)

    if ros2:
        robot = Child(name("ros2"), lambda: spawn_cell_process(
            ROS2_BRIDGE, cell, scenario, zenoh_port, 0, 0, login("controller"), rest))  # fmt: skip
    else:
        robot = Child(name("controller"), lambda: spawn_cell_process(
            CONTROLLER, cell, scenario, zenoh_port, 0, rt, login("controller"), rest))  # fmt: skip
    return [  # the robot first: the worker tracks it
        robot,
        Child(name("worker"), lambda: spawn_cell_process(
            WORKER, cell, scenario, zenoh_port, 0, rt, keep + login("worker"), mine)),
        Child(name("replayer"), lambda: spawn_cell_process(
            REPLAYER, cell, scenario, zenoh_port, REPLAYER_NICE, 0, login("tracker"), rest)),
    ]  # fmt: skip


def frame_loop(
    pairs: list[tuple[Any, Any]],
    frame_hz: float,
    duration_s: float | None,
    each: Callable[[], None] | None = None,
) -> None:
    """Draw every (cell view, dashboard) pair ``frame_hz`` times a second (and run ``each``)
    until Ctrl-C or ``duration_s``."""
    period = 1.0 / frame_hz
    t_end = None if duration_s is None else time.monotonic() + duration_s
    while (t_end is None or time.monotonic() < t_end) and not _STOP.is_set():
        t0 = time.monotonic()
        for view, dash in pairs:
            _show(view, dash)
        if each is not None:
            each()
        time.sleep(max(period - (time.monotonic() - t0), 0.0))


def _show(view: Any, dash: Any) -> None:
    frame = view.poll()
    if frame is not None:
        dash.update(frame)
    elif dash.panels is not None:  # until the first verdict: what the worker is doing
        dash.panels.show_waiting(view.waiting_status())


def _print_urls(
    names: list[str], scenario: str, urls: dict[str, str], api_url: str, zenoh_port: int,
    creds_path: Path, tokens_path: Path, tokens: dict[str, str] | None,
) -> None:  # fmt: skip
    for c in names:
        print(f"SaRA cell {c!r}, scenario {scenario!r}", flush=True)
        print(f"  3D dashboard   {urls[c]}", flush=True)
    print(f"  cells + API    {api_url}/   (OpenAPI docs: {api_url}/docs)", flush=True)
    print(f"  zenoh router   tcp/127.0.0.1:{zenoh_port}   (Ctrl-C stops everything)", flush=True)
    print(f"  zenoh users    tracker, controller, editor: passwords in {creds_path}")
    if tokens is not None:
        print(f"  API changes need 'Authorization: Bearer <token>'; tokens: {tokens_path}")
        print("  dashboard changes: sign in with a token in its Access panel")


MAX_CELLS = 8
"""Cells one ``serve`` runs at most (each a worker at real-time priority: see
docs/measurements/2026-11-26-many-cells.md for what this machine carries)."""
CONTROLLER, REPLAYER = "sara_app.peers.controller", "sara_app.peers.replayer"
ROS2_BRIDGE = "sara_app.ros2.bridge"
"""Started instead of the reference controller when the scenario enables ``ros2``."""
WORKER = "sara_app.processes.worker_start"
"""The worker as serve starts it: it says ``starting`` while its modules load."""
ROUTER = "sara_app.bus.router"


def _connect(port: int, auth: dict[str, Any], sup: Supervisor, wait_s: float = 30.0) -> Bus:
    """The dashboard's and API's session, once the router (just started) listens."""
    return _connect_until(port, auth, lambda: bool(sup.status()["router"]["running"]), wait_s)


def connect_when_listening(port: int, router: subprocess.Popen[bytes], wait_s: float = 30.0) -> Bus:
    """A session to a router process without access control, once it listens."""
    return _connect_until(port, None, lambda: router.poll() is None, wait_s)


def _connect_until(port: int, auth: dict[str, Any] | None, alive: Any, wait_s: float) -> Bus:
    t_end = time.monotonic() + wait_s
    while True:
        try:
            return Bus.client(port, timeout_ms=1000, auth=auth)
        except SaraError:
            if time.monotonic() > t_end or not alive():
                raise
            time.sleep(0.2)


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


def _silent_for(seen: Silence | None, sup: Supervisor, worker: str) -> float | None:
    """How long ``worker`` is known to have been silent (:meth:`CellRegistry.silence`) when its
    newest verdict came from the worker process running now through the router running now
    (:meth:`Supervisor.hang_age`), else None. Known, not merely seen: this process's threads
    run at a lowered priority, and on a loaded machine the registry's drain fell seconds behind
    the verdicts queued for it (two cells: 1 000 a second); its age of the newest verdict then
    grew while the workers ran, and both were killed as hung (the CI of 2026-12-01)."""
    if seen is None:
        return None
    now = time.monotonic()
    if sup.hang_age(now, now - seen.age_s, worker) is None:
        return None
    return seen.silent_s


_STOP = threading.Event()
"""Set by Ctrl-C / SIGTERM under ``sara-app serve``: the loop ends at its next frame."""


def _interrupt(signum: int, _frame: object) -> None:
    """Ctrl-C and SIGTERM end ``serve`` at its next frame (then the worker and the replayer are
    stopped: they run in their own sessions and would otherwise outlive it). A flag, not an
    exception: a KeyboardInterrupt raised anywhere in the display code (inside a lock of the
    viewer's or zenoh's threads) could leave the shutdown waiting on that lock."""
    _STOP.set()


def main_for_cli(
    scenario: str,
    cell: str,
    zenoh_port: int,
    viewer_port: int,
    api_port: int,
    duration_s: float | None,
    api_host: str = "127.0.0.1",
    require_token: bool = False,
    cells: int = 1,
    log_level: str = "info",
    pin_cpus: bool = True,
    watch_machine: bool = False,
    idle_poll: bool = False,
) -> NoReturn:
    os.environ[LOG_LEVEL_ENV] = log_level  # the children's level too
    # the libraries' INFO (uvicorn, viser, websockets) is theirs, not the user's: WARNING
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s serve %(message)s")
    logging.getLogger("sara_app").setLevel(log_level.upper())
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)  # a service manager's stop: like Ctrl-C
    # `kill -USR1 <pid>` prints every thread's stack to stderr: for a serve that does not stop
    # (C-level, so it works while the main thread is blocked outside the interpreter)
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    try:
        rc = serve(
            scenario,
            cell=cell,
            zenoh_port=zenoh_port,
            viewer_port=viewer_port,
            api_port=api_port,
            duration_s=duration_s,
            api_host=api_host,
            require_token=require_token,
            cells=cells,
            pin_cpus=pin_cpus,
            watch_machine=watch_machine,
            idle_poll=idle_poll,
        )
    except SaraError as e:
        print(f"error: {e}", file=sys.stderr)
        rc = 2
    _exit_now(rc)


def _exit_now(code: int) -> NoReturn:
    """End this process once :func:`serve` has stopped everything, without the interpreter's
    teardown of the display side's objects (~250k, numba's and pinocchio's modules): it runs
    on this thread at ``DISPLAY_NICE``, and beside two busy processes it took 12-30 s after
    everything had stopped (Ctrl-C to exit 13 s to over 30 s; 1.1 s of it the stops). What a
    normal exit does first is kept: non-daemon threads are waited for, the exit handlers run
    (logging's flush among them), the standard streams are flushed."""
    for t in threading.enumerate():
        if t is not threading.current_thread() and not t.daemon:
            t.join()
    atexit._run_exitfuncs()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


__all__ = ["serve", "main_for_cli", "DEFAULT_SCENARIO", "Path"]
