"""The retire route on a real worker (in a thread) over real zenoh: a person known only from a
refused message is forgotten on an operator's request, every request is in the audit log under
the request's user (the token's, not a name in the body), and a person the worker does not know
is refused (and audited)."""

from __future__ import annotations

import shutil
import time
import warnings
from pathlib import Path

with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message=".*httpx.*deprecated")
    from fastapi.testclient import TestClient

from waiting import wait_until as _until
from worker_thread import running_worker

from sara_app.api import CellRegistry, create_app
from sara_app.bus import keys
from sara_app.bus.session import Bus, free_port
from sara_app.ops.audit import AuditLog
from sara_app.scenario import load_scenario, scenarios_dir

CELL = "retire1"
TOKEN = "t" * 24


def test_retire_forgets_a_ghost_and_every_request_is_audited(tmp_path: Path) -> None:
    folder = tmp_path / "scenarios"
    shutil.copytree(scenarios_dir(), folder)
    port = free_port()
    sc = load_scenario("empty_cell", folder)
    with Bus.router(port), CellRegistry.connect(port) as reg, Bus.client(port) as wbus, \
            Bus.client(port) as other, \
            running_worker(CELL, sc, wbus, status_hz=10.0) as worker:  # fmt: skip
        audit = AuditLog(tmp_path / "audit.sqlite")
        app = create_app(reg, folder, audit=audit, tokens={TOKEN: "anna"})
        client = TestClient(app, headers={"authorization": f"Bearer {TOKEN}"})
        _until(lambda: client.get(f"/api/cells/{CELL}").is_success, 20.0)
        # garbage on a person's key: the person is known (unseen) from then on
        other.session.put(keys.skeleton_key(CELL, "ghost"), b"{broken")
        _until(lambda: "ghost" in worker.presence.tracks)
        body = {"user": "mallory", "reason": "tracker replaced; nobody there"}
        r = client.post(f"/api/cells/{CELL}/humans/ghost/retire", json=body)
        assert r.status_code == 409 and "still reported" in r.text  # the stream was just now
        assert "ghost" in worker.presence.tracks
        time.sleep(sc.inputs.tracker_timeout_s + 0.05)  # nothing more on the key
        r = client.post(f"/api/cells/{CELL}/humans/ghost/retire", json=body)
        assert r.status_code == 200, r.text
        assert "ghost" not in worker.presence.tracks
        r = client.post(f"/api/cells/{CELL}/humans/ghost/retire", json=body)
        assert r.status_code == 409 and "not known" in r.text
        bad = client.post(f"/api/cells/{CELL}/humans/ghost/retire", json={"user": "x"})
        assert bad.status_code == 422
        rows = client.get(f"/api/cells/{CELL}/humans/audit").json()
        assert [(x["human_id"], x["outcome"], x["user"]) for x in rows] == [
            ("ghost", "refused", "anna"),
            ("ghost", "applied", "anna"),
            ("ghost", "refused", "anna"),
        ]
        assert rows[1]["reason"] == body["reason"] and "still reported" in rows[2]["detail"]
        requests = client.get("/api/requests/audit").json()
        assert [x["user"] for x in requests] == ["anna"] * 4  # the same user in every row
