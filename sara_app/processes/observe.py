"""``sara-app observe``: the dashboards and the REST service for cells that run elsewhere, on a
router that is already running (a deployment on several machines, docs/deployment.md).

It starts no cell process: it connects to the router as the ``editor`` user (credentials are
required beyond loopback), waits for each cell's worker to announce its scenario (the robot to
draw), and then runs one 3D view per cell, the what-if and report jobs and the API, as
``sara-app serve`` does for its own cells. Edits made here go through the same validated,
audited path to the cells' workers.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from sara_app.api.guard import load_tokens
from sara_app.bus import keys
from sara_app.bus.access import Credentials, client_auth
from sara_app.bus.codec import Decoder
from sara_app.bus.messages import ScenarioStateMsg
from sara_app.bus.session import Bus
from sara_app.errors import ParameterError, SaraError
from sara_app.geometry.poses import pose_from_xyz_rpy
from sara_app.ops.audit import default_data_dir
from sara_app.scenario import Scenario, parse_scenario, scenarios_dir

ANNOUNCE_WAIT_S = 30.0
"""How long to wait for a cell's worker to announce its scenario (it does so every second)."""


def announced_scenario(bus: Bus, cell: str, wait_s: float = ANNOUNCE_WAIT_S) -> Scenario:
    """The scenario ``cell``'s worker runs, as it announces it; :class:`ParameterError` when
    none comes within ``wait_s`` (no worker of that cell on this router)."""
    sub = bus.subscribe(keys.scenario_key(cell), Decoder())
    try:
        t_end = time.monotonic() + wait_s
        while time.monotonic() < t_end:
            for d in sub.drain().messages:
                if isinstance(d.msg, ScenarioStateMsg):
                    return parse_scenario(d.msg.scenario, f"the scenario of cell {cell!r}")
            time.sleep(0.1)
    finally:
        sub.close()
    raise ParameterError(
        f"cell {cell!r} announced no scenario within {wait_s:g} s; expected its worker running "
        "on this router (sara-app worker --cell ...)"
    )


def observe(
    cells: list[str],
    *,
    router_host: str = "127.0.0.1",
    zenoh_port: int = 7447,
    credentials: str | None = None,
    viewer_port: int = 8080,
    api_port: int = 8000,
    api_host: str = "127.0.0.1",
    require_token: bool = False,
    duration_s: float | None = None,
    frame_hz: float = 20.0,
) -> int:
    """Run until Ctrl-C (or ``duration_s``); returns the exit code."""
    from sara_app.api.app import create_app
    from sara_app.api.registry import CellRegistry
    from sara_app.api.server import ApiServer
    from sara_app.dashboard.access import DashboardAccess
    from sara_app.dashboard.bridge import CellView
    from sara_app.dashboard.viewer import Dashboard
    from sara_app.ops.jobs import JobRunner
    from sara_app.processes.serve import _is_loopback, frame_loop

    if not cells:
        raise ParameterError("no cell given; expected --cell NAME (repeatable)")
    auth = None if credentials is None else client_auth("editor", Credentials(credentials))
    exposed = not _is_loopback(api_host)
    tokens_path = default_data_dir() / "api_tokens.json"
    tokens = load_tokens(tokens_path, create=True) if (require_token or exposed) else None
    folder = scenarios_dir()
    closers: list[Any] = []
    with Bus.client(zenoh_port, router_host, auth=auth) as hub:
        try:
            jobs = JobRunner()
            closers.append(jobs.close)
            registry = CellRegistry(hub).start()  # the views follow its verdicts
            closers.append(registry.close)
            views, dashes, urls = {}, {}, {}
            for i, c in enumerate(cells):
                sc = announced_scenario(hub, c)
                T = pose_from_xyz_rpy(sc.robot.base_xyz_m, sc.robot.base_rpy_rad)
                dash = Dashboard(robot=sc.robot.name, T_world_base=T,
                                 access=DashboardAccess(tokens, c))  # fmt: skip
                view = CellView(c, hub, dash, sc, folder, verdicts=registry)
                urls[c] = dash.start(port=viewer_port + i, on_select_scenario=view.select,
                                     on_save_as=view.save_as, on_params_edit=view.edit)  # fmt: skip
                closers.append(dash.stop)
                view.refresh_panels()
                panels = view.attach_whatif(jobs)
                if panels is not None:
                    closers.append(panels.close)
                views[c], dashes[c] = view, dash
            app = create_app(
                registry, folder, viewer_url=urls[cells[0]], tokens=tokens,
                require_token=tokens is not None, hosts=() if not exposed else (api_host,),
                jobs=jobs, viewers=urls,
            )  # fmt: skip
            api = ApiServer(app, host=api_host, port=api_port)
            api_url = api.start().rstrip("/")
            closers.append(api.stop)
            for c in cells:
                print(f"SaRA cell {c!r} on tcp/{router_host}:{zenoh_port}: 3D view {urls[c]}",
                      flush=True)  # fmt: skip
            print(f"  cells + API    {api_url}/   (Ctrl-C stops)", flush=True)
            frame_loop([(views[c], dashes[c]) for c in cells], frame_hz, duration_s)
            return 0
        except KeyboardInterrupt:
            return 0
        except SaraError as e:
            print(f"error: {e}", flush=True)
            return 2
        finally:
            for close in reversed(closers):
                close()


__all__ = ["announced_scenario", "observe", "Path"]
