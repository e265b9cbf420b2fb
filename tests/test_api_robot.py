"""The re-plan route on a real worker (in a thread) and the reference controller (in a thread)
over real zenoh: a robot moved by hand while its controller ran stays a tracking fault; an
operator's re-plan confirming another position is refused, one confirming where the controller
says the robot stands makes the cell move on from there; every request is in the audit log
under the request's user, with the positions confirmed. The positions the operator confirms
are the ones the cell's status reports."""

from __future__ import annotations

import shutil
import threading
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message=".*httpx.*deprecated")
    from fastapi.testclient import TestClient

from waiting import wait_until
from worker_thread import running_worker

from sara_app.api import CellRegistry, create_app
from sara_app.bus.heartbeat import Heartbeat
from sara_app.bus.session import Bus, free_port
from sara_app.ops.audit import AuditLog
from sara_app.peers.controller import Controller
from sara_app.scenario import load_scenario, scenarios_dir


def _until(pred: Any, timeout_s: float = 20.0, what: str = "the condition") -> Any:
    return wait_until(pred, timeout_s, what)


CELL = "replan1"
TOKEN = "r" * 24
LONG = "s" * 24  # a token whose user's name is longer than a bus message's user may be


def test_replan_after_a_hand_move_and_every_request_audited(tmp_path: Path) -> None:
    folder = tmp_path / "scenarios"
    shutil.copytree(scenarios_dir(), folder)
    port = free_port()
    sc = load_scenario("empty_cell", folder)
    with Bus.router(port), CellRegistry.connect(port) as reg, Bus.client(port) as wbus, \
            Bus.client(port) as cbus, Heartbeat(cbus, CELL), \
            running_worker(CELL, sc, wbus, status_hz=10.0) as worker:  # fmt: skip
        robot = Controller(CELL, sc, cbus)
        thread = threading.Thread(target=robot.run, daemon=True)
        thread.start()
        try:
            audit = AuditLog(tmp_path / "audit.sqlite")
            app = create_app(reg, folder, audit=audit, tokens={TOKEN: "anna", LONG: "u" * 80},
                             require_token=True)  # fmt: skip
            client = TestClient(app, headers={"authorization": f"Bearer {TOKEN}"})
            _until(lambda: client.get(f"/api/cells/{CELL}").is_success, what="the cell")
            _until(lambda: worker.robot_in.bound and worker.last is not None
                   and worker.last.mode == "intended", what="moving, tracked")  # fmt: skip
            r = TestClient(app, headers={"authorization": f"Bearer {LONG}"}).post(
                f"/api/cells/{CELL}/robot/replan", json={"q": robot.q.tolist(), "reason": "x"}
            )  # while it moves: refused, not a 500 for the user's long name (probe, 2026-11-30)
            assert r.status_code == 409 and "not at rest" in r.text, r.text
            with robot._lock:  # noqa: SLF001 - moved by hand: 0.3 rad on joint 0, at rest
                moved = robot.q.copy()
                moved[0] += 0.3
                robot.q, robot.v = moved, np.zeros_like(moved)
                robot.command, robot.points, robot.braking = None, [], False
            _until(
                lambda: (
                    worker.shield.at_rest
                    and worker.last is not None
                    and any("tracking error" in f for f in worker.last.faults)
                ),
                what="the tracking fault",
            )
            time.sleep(0.3)
            assert worker.last is not None and worker.last.mode != "intended"
            wrong = moved.copy()
            wrong[2] -= 0.1
            url = f"/api/cells/{CELL}/robot/replan"
            r = client.post(url, json={"q": wrong.tolist(), "reason": "moved by hand"})
            assert r.status_code == 409 and "from the position confirmed" in r.text, r.text
            assert f"{moved[0]:.4f}" in r.text  # the refusal names where the controller says
            for bad in ({"q": ["0.1"] * 7, "reason": "x"}, {"q": [], "reason": "x"},
                        {"q": [True] * 7, "reason": "x"}, {"q": moved.tolist()}):  # fmt: skip
                assert client.post(url, json=bad).status_code == 422, bad
            assert (
                client.post(
                    "/api/cells/nowhere/robot/replan", json={"q": moved.tolist(), "reason": "x"}
                ).status_code
                == 404
            )
            assert TestClient(app).post(url, json={"q": moved.tolist(), "reason": "x"}
                                        ).status_code == 401  # no token  # fmt: skip

            def reported() -> list[float] | None:  # what the operator reads and confirms
                q = client.get(f"/api/cells/{CELL}").json()["robot_q_measured"]
                return q if q is not None and np.allclose(q, moved) else None

            _until(lambda: reported() is not None, what="the cell's status")
            r = client.post(url, json={"q": reported(), "reason": "moved by hand"})
            assert r.status_code == 200, r.text
            _until(lambda: worker.last is not None and worker.last.mode == "intended",
                   what="moving again")  # fmt: skip
            _until(lambda: float(np.max(np.abs(robot.q - moved))) > 0.01, what="the robot")
            rows = client.get(f"/api/cells/{CELL}/robot/audit").json()
            assert [(x["action"], x["outcome"], x["user"]) for x in rows] == [
                ("replan", "applied", "anna"),
                ("replan", "refused", "anna"),
                ("replan", "refused", "u" * 80),
            ]
            assert rows[0]["q_rad"] == moved.tolist() and rows[1]["q_rad"] == wrong.tolist()
            assert "from the position confirmed" in rows[1]["detail"]
        finally:
            robot.stop_event.set()
            thread.join(10)
