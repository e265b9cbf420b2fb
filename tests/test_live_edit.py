"""Live edits over the API change what the project's cell worker verifies, end to end over real
zenoh on 127.0.0.1 (a router, the worker in a thread, a skeleton publisher on its own session,
the REST service's registry on another):

- a human-model parameter (the sensor delay) raised over the API turns a person who was safely
  far into a reason to brake, and lowering it again lets the robot work;
- new task waypoints over the API move the robot's occupancy capsules to the new path;
- a threshold edit over PUT is acknowledged and is then part of the worker's scenario, on top of
  the earlier edit (the edit starts from the scenario the worker runs, not from the file);
- in PFL mode, thresholds lowered over PUT below the links' energies make the robot brake near a
  person it passed (slowed down) before.
"""

from __future__ import annotations

import importlib
import itertools
import shutil
import threading
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message=".*httpx.*deprecated")
    from fastapi.testclient import TestClient

from sara_app.api import CellRegistry, create_app
from sara_app.bus import keys
from sara_app.bus.heartbeat import Heartbeat
from sara_app.bus.messages import OccupancyMsg, RobotCommandMsg, SkeletonMsg, VerdictMsg
from sara_app.bus.session import Bus, Subscription, free_port
from sara_app.human.params import load_param_set
from sara_app.human.skeleton import skeleton
from sara_app.ops.audit import AuditLog
from sara_app.runtime.worker import CellWorker
from sara_app.safety.thresholds import CONTACTS, REGIONS
from sara_app.scenario import load_scenario, scenarios_dir
from sara_app.sim.motions import measured

# live cells whose rates and timings the assertions read: no other test runs beside them
pytestmark = [pytest.mark.exclusive, pytest.mark.usefixtures("idle_cpus_poll")]

CELL = "live1"
STANDING = {  # a person standing upright, feet at x = 0
    "head": (0, 0, 1.65),
    "neck": (0, 0, 1.45),
    "pelvis": (0, 0, 0.95),
    "l_shoulder": (0, 0.18, 1.42),
    "r_shoulder": (0, -0.18, 1.42),
    "l_elbow": (0, 0.22, 1.15),
    "r_elbow": (0, -0.22, 1.15),
    "l_wrist": (0, 0.24, 0.9),
    "r_wrist": (0, -0.24, 0.9),
    "l_hip": (0, 0.1, 0.92),
    "r_hip": (0, -0.1, 0.92),
    "l_knee": (0, 0.1, 0.5),
    "r_knee": (0, -0.1, 0.5),
    "l_ankle": (0, 0.1, 0.08),
    "r_ankle": (0, -0.1, 0.08),
}


class Person:
    """Publishes a standing person at ``x_m`` in front of the robot at 60 Hz (own session)."""

    def __init__(self, live: Live, x_m: float) -> None:
        port = live.port
        live.heartbeat.people = {"p1"}  # the tracker sees them
        names = skeleton("full").joints
        self.y = np.array([STANDING[n] for n in names], float) + [x_m, 0.0, 0.0]
        self.rng = np.random.default_rng(1)
        self.bus = Bus.client(port)
        self.pub = self.bus.publisher(keys.skeleton_key(CELL, "p1"))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(1 / 60):
            seq = self.pub.next_seq()
            y = measured(self.y, 0.002, self.rng)  # a real tracker's noise
            self.pub.put(SkeletonMsg.from_arrays("full", y, seq=seq, stamp_s=time.time()))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.bus.close()


class Live:
    def __init__(
        self, port: int, worker: CellWorker, client: TestClient, watch: Bus, hb: Heartbeat
    ) -> None:
        self.port, self.worker, self.client, self.heartbeat = port, worker, client, hb
        self.verdicts = watch.subscribe(keys.verdict_key(CELL), fifo=True, capacity=20000)
        self.occ = watch.subscribe(keys.occupancy_key(CELL), fifo=True, capacity=2000)
        self.cmds = watch.subscribe(keys.robot_command_key(CELL), fifo=True, capacity=20000)

    def collect(self, sub: Subscription, kind: type, seconds: float) -> list[Any]:
        sub.drain()  # only what arrives from now on
        out: list[Any] = []
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:
            out += [d.msg for d in sub.drain().messages if isinstance(d.msg, kind)]
            time.sleep(0.02)
        return out

    def failsafe_share(self, seconds: float) -> float:
        v = self.collect(self.verdicts, VerdictMsg, seconds)
        assert len(v) > 50, "the worker must keep publishing verdicts"
        return sum(m.mode == "failsafe" for m in v) / len(v)


@pytest.fixture
def live(tmp_path: Path) -> Iterator[Live]:
    folder = tmp_path / "scenarios"
    shutil.copytree(scenarios_dir(), folder)
    port = free_port()
    with (
        Bus.router(port),
        CellRegistry.connect(port) as reg,
        Bus.client(port) as wbus,
        Bus.client(port) as watch,
    ):
        worker = CellWorker(CELL, load_scenario("empty_cell", folder), wbus, status_hz=10.0)
        thread = threading.Thread(target=worker.run, daemon=True)
        thread.start()
        hb = Heartbeat(watch, CELL).start()
        client = TestClient(create_app(reg, folder, audit=AuditLog(tmp_path / "audit.sqlite")))
        try:
            deadline = time.monotonic() + 20
            while not client.get(f"/api/cells/{CELL}").is_success:
                assert time.monotonic() < deadline, "the worker never showed up"
                time.sleep(0.05)
            yield Live(port, worker, client, watch, hb)
        finally:
            hb.stop()
            worker.stop_event.set()
            thread.join(10)


def _scenario_with(live: Live, **changes: Any) -> dict[str, Any]:
    data = live.worker.cell.scenario.model_dump(mode="json")
    data.update(changes)
    return data


def test_delay_edit_flips_the_verdict_for_a_fixed_person(live: Live) -> None:
    person = Person(live, 1.4)  # 1.4 m away: free for the sets at a 10 ms delay
    try:
        assert live.failsafe_share(1.5) < 0.1
        named = load_param_set("schepp2022_table1").model_dump(mode="json")
        slow = {**named, "name": "slow_sensor", "delay_s": 0.3}
        r = live.client.post(  # another human model: confirmed (sara_app.ops.loosening)
            f"/api/cells/{CELL}/scenario?confirm=true", json=_scenario_with(live, human_params=slow)
        )
        assert r.status_code == 200, r.text
        assert live.worker.cell.params.delay_s == 0.3
        assert live.failsafe_share(1.5) > 0.3  # the grown sets reach the robot: it brakes
        # a threshold edit on top: acknowledged, in the worker's scenario, delay kept
        body = {"region": "hand", "contact": "constrained", "shape": "blunt", "energy_J": 0.1}
        r = live.client.put(f"/api/cells/{CELL}/thresholds", json={**body, "user": "e2e"})
        assert r.status_code == 200, r.text
        sc = live.worker.cell.scenario
        assert [o.model_dump() for o in sc.shield.pfl.overrides] == [body]
        assert live.worker.cell.params.delay_s == 0.3  # the earlier edit is not lost
        audit = live.client.get(f"/api/cells/{CELL}/thresholds/audit").json()
        # the request's user (no token here: "local"), never the name in the body
        assert audit[0]["outcome"] == "applied" and audit[0]["user"] == "local"
        r = live.client.post(
            f"/api/cells/{CELL}/scenario?confirm=true",
            json=_scenario_with(live, human_params="schepp2022_table1"),
        )
        assert r.status_code == 200, r.text
        assert live.failsafe_share(1.5) < 0.1  # back to a 10 ms delay: it works again
    finally:
        person.close()


def _outside_m(occ: list[OccupancyMsg], lo: np.ndarray, hi: np.ndarray) -> float:
    """How far the robot's interval capsule ends reach outside the per-link boxes ``lo``/``hi``
    ``(L, 3)``, over all messages (m)."""
    worst = -np.inf
    for m in occ:
        if m.robot is None:
            continue
        L = len(m.robot.link_names)
        ends = m.robot.capsules.arrays()[0].reshape(-1, L, 2, 3)  # (K, L, 2, 3)
        worst = max(worst, float(np.maximum(ends - hi[:, None], lo[:, None] - ends).max()))
    return worst


def test_waypoint_edit_moves_the_robot_occupancy(live: Live) -> None:
    new_wps = [[-0.1, 0.0, 0.0, -2.2, 0.0, 2.2, 0.8], [0.1, 0.0, 0.0, -2.2, 0.0, 2.2, 0.8]]
    path = np.linspace(new_wps[0], new_wps[1], 50)
    ends_path = live.worker.cell.robot.link_capsules_batch(path)  # (50, L, 2, 3): on its base
    lo, hi = ends_path.min(axis=(0, 2)), ends_path.max(axis=(0, 2))  # (L, 3) per link
    before = live.collect(live.occ, OccupancyMsg, 1.0)
    assert _outside_m(before, lo, hi) > 0.2  # the shipped task sweeps elsewhere
    task = {**live.worker.cell.scenario.task.model_dump(mode="json"), "waypoints_rad": new_wps}
    r = live.client.post(f"/api/cells/{CELL}/scenario", json=_scenario_with(live, task=task))
    assert r.status_code == 200, r.text
    deadline = time.monotonic() + 10.0
    while True:  # the robot leaves the old path for the new one
        outside = _outside_m(live.collect(live.occ, OccupancyMsg, 0.5), lo, hi)
        if outside < 0.02 or time.monotonic() > deadline:
            break
    # every capsule end of every interval lies within 2 cm of the new path's link boxes
    assert outside < 0.02, outside
    cmds = live.collect(live.cmds, RobotCommandMsg, 0.5)
    assert np.all(np.abs([m.q[0] for m in cmds]) <= 0.1 + 1e-6)


def test_pfl_threshold_lowered_below_the_link_energies_makes_the_robot_brake(
    live: Live,
) -> None:
    """PFL mode, a person 0.8 m in front of the robot: the robot passes them slowed down (it
    never brakes in simulation) at the source thresholds; with every blunt threshold lowered over
    PUT to 1 uJ, far below any moving link's energy, the worker brakes instead."""
    # the PFL kernels loaded (compiled, on a fresh checkout) before the switch: a cold compile
    # on a busy 2-core machine can outlast the API's edit timeout (then the answer is 504, "it
    # may still apply it", which is not what this test is about)
    importlib.import_module("sara_app.safety.pfl_cycle")
    shield = {**live.worker.cell.scenario.shield.model_dump(mode="json"), "mode": "pfl"}
    r = live.client.post(f"/api/cells/{CELL}/scenario", json=_scenario_with(live, shield=shield))
    assert r.status_code == 200, r.text
    person = Person(live, 0.8)
    try:
        v = live.collect(live.verdicts, VerdictMsg, 2.0)
        assert v and {m.safety_mode for m in v} == {"pfl"}
        share_before = sum(m.mode == "failsafe" for m in v) / len(v)
        assert share_before < 0.4  # about 0 in simulation; a loaded machine delays cycles
        assert min(m.speed_scale for m in v if m.speed_scale is not None) < 0.5  # it slows
        for region, contact in itertools.product(REGIONS, CONTACTS):
            body = {"region": region, "contact": contact, "shape": "blunt", "energy_J": 1e-6}
            r = live.client.put(f"/api/cells/{CELL}/thresholds", json=body)
            assert r.status_code == 200, r.text
        assert len(live.worker.cell.scenario.shield.pfl.overrides) == 10
        assert live.worker.cell.scenario.shield.mode == "pfl"
        share_after = live.failsafe_share(2.0)
        assert share_after > max(0.5, share_before + 0.3), (share_before, share_after)
    finally:
        person.close()


def _status_checksum(live: Live, not_equal: str | None = None) -> str:
    deadline = time.monotonic() + 10.0
    while True:
        got = live.client.get(f"/api/cells/{CELL}").json().get("config_sha256")
        if got and got != not_equal:
            return str(got)
        assert time.monotonic() < deadline, f"no new checksum in the status (still {got})"
        time.sleep(0.05)


def test_the_report_checksum_is_the_running_workers_and_changes_with_any_edit(
    live: Live,
) -> None:
    """The worker reports its configuration checksum; an evidence report made over the API
    (a background job) prints the same one; a threshold edit changes the worker's, which then
    equals the checksum of the edited scenario and no longer the report's."""
    from sara_app.cell.checksum import config_checksum

    running = _status_checksum(live)
    assert running == config_checksum(live.worker.cell.scenario)
    r = live.client.post(f"/api/cells/{CELL}/report", params={"duration_s": 0.3, "episodes": 0})
    assert r.status_code == 202, r.text
    job = r.json()["id"]
    deadline = time.monotonic() + 240
    while (st := live.client.get(f"/api/jobs/{job}").json())["state"] == "running":
        assert time.monotonic() < deadline, st
        time.sleep(0.5)
    assert st["state"] == "done", st
    assert st["checksum"] == running
    page = live.client.get(st["report_url"])
    assert page.status_code == 200 and running in page.text
    body = {"region": "hand", "contact": "constrained", "shape": "blunt", "energy_J": 0.1}
    r = live.client.put(f"/api/cells/{CELL}/thresholds", json={**body, "user": "auditor"})
    assert r.status_code == 200, r.text
    edited = _status_checksum(live, not_equal=running)
    assert edited == config_checksum(live.worker.cell.scenario) != st["checksum"]


def test_the_cli_reports_the_running_cell_and_says_when_a_file_is_not_it(
    live: Live, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """After a live threshold edit, `sara-app report --cell` (over the API, a real HTTP server)
    prints the running cell's checksum and says so on the report's first line; a report of
    the scenario file says on its first line that it is not the running cell, and that the
    cell runs a different configuration."""
    from sara_app.api.server import ApiServer
    from sara_app.cli import main

    running = _status_checksum(live)
    body = {"region": "hand", "contact": "constrained", "shape": "blunt", "energy_J": 0.1}
    assert live.client.put(f"/api/cells/{CELL}/thresholds", json=body).status_code == 200
    edited = _status_checksum(live, not_equal=running)
    server = ApiServer(live.client.app, port=0)
    url = server.start()
    try:
        out = tmp_path / "cell.html"
        args = ["--cell", CELL, "--api", url, "--duration", "0.3", "--episodes", "0", "--quiet"]
        assert main(["report", *args, "--out", str(out)]) == 0
        said = capsys.readouterr().out
        assert f"checksum {edited}; the cell runs {edited}: equal" in said, said
        first = out.read_text().split("<body>", 1)[1][:300]
        assert "describes the running cell" in first and edited in out.read_text()
        capsys.readouterr()
        out = tmp_path / "file.html"
        assert main(["report", "empty_cell", *args, "--modes", "ssm", "--out", str(out)]) == 0
        said = capsys.readouterr().out
        assert "NOT a running cell" in said.splitlines()[0]
        assert f"runs checksum {edited}: a DIFFERENT configuration" in said, said
        assert "NOT a running cell" in out.read_text().split("<body>", 1)[1][:300]
    finally:
        server.stop()
