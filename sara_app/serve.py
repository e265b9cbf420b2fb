"""``sara-app serve``: the whole cell on one machine, no setup.

Processes: this one (a Zenoh router on 127.0.0.1, the viser dashboard and the FastAPI service),
a cell worker and a replayer (the scenario's people, published over Zenoh as a tracker would).
The safety loop runs in the worker process and never waits for the view. Ctrl-C stops all.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from sara_app.bus.session import Bus
from sara_app.cell import base_pose
from sara_app.errors import SaraError
from sara_app.scenario import load_scenario, scenarios_dir

log = logging.getLogger("sara_app.serve")
DEFAULT_SCENARIO = "punches"


def _spawn(module: str, cell: str, scenario: str, port: int) -> subprocess.Popen[bytes]:
    cmd = [
        sys.executable,
        "-m",
        module,
        "--cell",
        cell,
        "--scenario",
        scenario,
        "--port",
        str(port),
    ]
    return subprocess.Popen(cmd, start_new_session=True)


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    t_end = time.monotonic() + 5.0
    for p in procs:
        try:
            p.wait(timeout=max(t_end - time.monotonic(), 0.1))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def serve(
    scenario: str = DEFAULT_SCENARIO,
    *,
    cell: str = "cell1",
    zenoh_port: int = 7447,
    viewer_port: int = 8080,
    api_port: int = 8000,
    duration_s: float | None = None,
    frame_hz: float = 20.0,
) -> int:
    """Run everything until Ctrl-C (or ``duration_s``); returns the exit code."""
    from sara_app.api.app import create_app
    from sara_app.api.registry import CellRegistry
    from sara_app.api.server import ApiServer
    from sara_app.dashboard.bridge import CellView
    from sara_app.dashboard.viewer import Dashboard

    folder = scenarios_dir()
    sc = load_scenario(scenario, folder)
    procs: list[subprocess.Popen[bytes]] = []
    hub = Bus.router(zenoh_port)
    dash = Dashboard(
        robot=sc.robot.name, T_world_base=base_pose(sc.robot.base_xyz_m, sc.robot.base_rpy_rad)
    )
    api = None
    registry = None
    try:
        procs = [
            _spawn("sara_app.worker", cell, scenario, zenoh_port),
            _spawn("sara_app.replayer", cell, scenario, zenoh_port),
        ]
        view = CellView(cell, hub, dash, sc, folder)
        viewer_url = dash.start(
            port=viewer_port,
            on_select_scenario=view.select,
            on_save_as=view.save_as,
            on_params_edit=view.edit,
        )
        view.refresh_panels()
        registry = CellRegistry(hub)
        registry.start()
        api = ApiServer(create_app(registry, folder, viewer_url=viewer_url), port=api_port)
        api_url = api.start().rstrip("/")
        print(f"SaRA cell {cell!r}, scenario {scenario!r}", flush=True)
        print(f"  3D dashboard   {viewer_url}", flush=True)
        print(f"  cells + API    {api_url}/   (OpenAPI docs: {api_url}/docs)", flush=True)
        print(
            f"  zenoh router   tcp/127.0.0.1:{zenoh_port}   (Ctrl-C stops everything)", flush=True
        )
        period = 1.0 / frame_hz
        t_end = None if duration_s is None else time.monotonic() + duration_s
        while t_end is None or time.monotonic() < t_end:
            t0 = time.monotonic()
            frame = view.poll()
            if frame is not None:
                dash.update(frame)
            dead = [p for p in procs if p.poll() is not None]
            if dead:
                print(
                    f"error: process {dead[0].pid} exited with code {dead[0].returncode}",
                    file=sys.stderr,
                )
                return 1
            time.sleep(max(period - (time.monotonic() - t0), 0.0))
        return 0
    except KeyboardInterrupt:
        return 0
    finally:
        _stop(procs)
        if api is not None:
            api.stop()
        if registry is not None:
            registry.close()
        dash.stop()
        hub.close()


def _interrupt(signum: int, _frame: object) -> None:
    """SIGTERM ends ``serve`` like Ctrl-C, so its worker and replayer are stopped too (they run
    in their own sessions and would otherwise outlive it)."""
    raise KeyboardInterrupt(f"signal {signum}")


def main_for_cli(
    scenario: str,
    cell: str,
    zenoh_port: int,
    viewer_port: int,
    api_port: int,
    duration_s: float | None,
) -> int:
    logging.basicConfig(level=logging.WARNING)
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    signal.signal(signal.SIGTERM, _interrupt)  # a service manager's stop: like Ctrl-C
    try:
        return serve(
            scenario,
            cell=cell,
            zenoh_port=zenoh_port,
            viewer_port=viewer_port,
            api_port=api_port,
            duration_s=duration_s,
        )
    except SaraError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


__all__ = ["serve", "main_for_cli", "DEFAULT_SCENARIO", "Path"]
