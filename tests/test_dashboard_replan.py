"""The dashboard's "Plan from where the robot stands" on a real viser server, a real worker and
the reference controller (threads) over real zenoh: the Status tab shows where the controller
reports a robot moved by hand; the button sends exactly that position, the worker plans from
there and the robot moves on; a refusal (the robot moving) is shown; both are audited as the
dashboard's robot actions and as requests."""

from __future__ import annotations

import shutil
import threading
from pathlib import Path
from typing import Any

import numpy as np
from waiting import wait_until
from worker_thread import running_worker

from sara_app.bus.heartbeat import Heartbeat
from sara_app.bus.session import Bus, free_port
from sara_app.dashboard.access import DashboardAccess
from sara_app.dashboard.bridge import CellView
from sara_app.dashboard.viewer import Dashboard
from sara_app.ops.audit import AuditLog
from sara_app.peers.controller import Controller
from sara_app.runtime.robot_link import REPLAN_STILL_S
from sara_app.scenario import load_scenario, scenarios_dir


def _until(pred: Any, timeout_s: float = 20.0, what: str = "the condition") -> Any:
    return wait_until(pred, timeout_s, what)


CELL = "dashreplan"


def test_the_status_tabs_replan_sends_the_position_it_shows(tmp_path: Path) -> None:
    folder = tmp_path / "scenarios"
    shutil.copytree(scenarios_dir(), folder)
    sc = load_scenario("empty_cell", folder)
    audit = AuditLog(tmp_path / "audit.sqlite")
    port = free_port()
    dash = Dashboard(access=DashboardAccess(None, CELL, audit))
    try:
        with Bus.router(port), Bus.client(port) as wbus, Bus.client(port) as vbus, \
                Bus.client(port) as cbus, Heartbeat(cbus, CELL), \
                running_worker(CELL, sc, wbus, status_hz=10.0) as worker:  # fmt: skip
            view = CellView(CELL, vbus, dash, sc, folder, ack_timeout_s=10.0, audit=audit)
            dash.start(port=free_port())
            view.refresh_panels()
            panels = dash.panels
            assert panels is not None and panels.on_replan == view.replan
            robot = Controller(CELL, sc, cbus)
            thread = threading.Thread(target=robot.run, daemon=True)
            thread.start()

            def shown() -> str:  # the dashboard's loop: the newest frame drawn
                frame = view.poll()
                if frame is not None:
                    dash.update(frame)
                return str(panels.robot_q.content)

            try:
                _until(lambda: "reports the robot at" in shown()
                       and worker.robot_in.bound and worker.last is not None
                       and worker.last.mode == "intended", what="moving, tracked")  # fmt: skip
                assert not panels.replan()  # while the robot moves: refused, and shown
                assert "not at rest" in panels.replan_message.content
                with robot._lock:  # noqa: SLF001 - moved by hand: 0.3 rad on joint 0, at rest
                    moved = robot.q.copy()
                    moved[0] += 0.3
                    robot.q, robot.v = moved, np.zeros_like(moved)
                    robot.command, robot.points, robot.braking = None, [], False
                text = f"[{moved[0]:.4f}, {moved[1]:.4f}"
                _until(lambda: text in shown() and worker.shield.at_rest, what="the position")
                link = worker.robot_in  # the worker takes it once it has stood still a while

                def still_s() -> float:
                    since, stamp = link.still_since_s, link.stamp_s
                    return -1.0 if since is None or stamp is None else stamp - since

                _until(lambda: still_s() >= REPLAN_STILL_S, what="standing still")
                assert worker.last is not None and worker.last.mode != "intended"
                assert panels.replan(), panels.replan_message.content
                _until(lambda: worker.last is not None and worker.last.mode == "intended",
                       what="moving again")  # fmt: skip
                _until(lambda: float(np.max(np.abs(robot.q - moved))) > 0.01, what="the robot")
            finally:
                robot.stop_event.set()
                thread.join(10)
        rows = audit.robot_actions(CELL)
        assert [(r["outcome"], r["via"], r["user"]) for r in rows] == [
            ("applied", "dashboard", "local"),
            ("refused", "dashboard", "local"),
        ]
        assert np.allclose(rows[0]["q_rad"], moved, atol=1e-4)  # what the tab showed
        assert "not at rest" in rows[1]["detail"]
        requests = [r["path"] for r in audit.requests()]
        assert requests.count(f"/dashboard/{CELL}/replan") == 2
    finally:
        dash.stop()
