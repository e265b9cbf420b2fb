"""The state in force survives restarts: a threshold edit applied over the API, then ``kill -9``
of the worker process and a restart with the same arguments: the worker runs the value the
audit log's newest 'applied' row records. Started with another scenario it begins afresh; an
unreadable state file is ignored, never half-used."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path
from typing import Any

with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message=".*httpx.*deprecated")
    from fastapi.testclient import TestClient

from sara_app.api import CellRegistry, create_app
from sara_app.bus.session import Bus, free_port
from sara_app.ops.audit import AuditLog
from sara_app.runtime.cell_state import CellState

CELL = "keep1"


def _worker(port: int, state: Path, scenario: str = "empty_cell") -> subprocess.Popen[bytes]:
    cmd = [sys.executable, "-m", "sara_app.runtime.worker", "--cell", CELL, "--scenario", scenario,
           "--port", str(port), "--state-dir", str(state)]  # fmt: skip
    return subprocess.Popen(cmd)


def _running(reg: CellRegistry, since: float, name: str = "empty_cell") -> dict[str, Any]:
    """The scenario ``name`` as announced by a worker started after ``since`` (its status
    says so, and its announcement has come: it follows the first status)."""
    t_end = time.monotonic() + 90.0
    while time.monotonic() < t_end:
        snap = reg.cell(CELL)
        fresh = snap and snap["online"] and snap["uptime_s"] < time.time() - since + 1
        time.sleep(0.2)  # the announcement of the same cycle as the status
        sc = reg.applied_scenario(CELL)
        if fresh and sc and sc["name"] == name:
            return sc
        time.sleep(0.1)
    raise AssertionError("the worker did not come up")


def _hand(sc: dict[str, Any]) -> float | None:
    got = [o["energy_J"] for o in sc["shield"]["pfl"]["overrides"] if o["region"] == "hand"]
    return got[-1] if got else None


def test_an_applied_threshold_survives_kill_9_and_matches_the_audit(tmp_path: Path) -> None:
    state = tmp_path / "cells"
    port = free_port()
    with Bus.router(port), CellRegistry.connect(port) as reg:
        client = TestClient(create_app(reg, audit=AuditLog(tmp_path / "audit.sqlite")))
        t0 = time.time()
        w = _worker(port, state)
        try:
            assert _hand(_running(reg, t0)) is None
            body = {"region": "hand", "contact": "constrained", "shape": "blunt",
                    "energy_J": 0.11, "user": "eng"}  # fmt: skip
            r = client.put(f"/api/cells/{CELL}/thresholds", json=body)
            assert r.status_code == 200, r.text
            w.send_signal(signal.SIGKILL)
            w.wait(10)
            t1 = time.time()
            w = _worker(port, state)
            restored = _running(reg, t1)
            audit = client.get(f"/api/cells/{CELL}/thresholds/audit").json()
            applied = [a for a in audit if a["outcome"] == "applied"]
            assert applied[0]["new_energy_J"] == _hand(restored) == 0.11
            # another scenario: a new decision, no edits carried over
            w.send_signal(signal.SIGKILL)
            w.wait(10)
            t2 = time.time()
            w = _worker(port, state, "standing_beside_path")
            fresh = _running(reg, t2, "standing_beside_path")
            assert fresh["name"] == "standing_beside_path" and _hand(fresh) is None
        finally:
            w.kill()
            w.wait(10)


def test_an_unreadable_state_is_ignored(tmp_path: Path) -> None:
    st = CellState(tmp_path, CELL)
    st.save("empty_cell", {"name": "x"}, 3)
    assert st.load("empty_cell") == ({"name": "x"}, 3)
    assert st.load("other") is None
    st.path.write_text("{not json")
    assert st.load("empty_cell") is None
    st.path.write_text('{"origin": "empty_cell", "scenario": 5}')
    assert st.load("empty_cell") is None
