"""The REST service: cells from bus messages, scenarios (read, validated save, no overwrite, no
traversal), parameter sets, event streams, the landing page; and one run with a real uvicorn
server, a real zenoh router and a fake worker answering scenario requests over zenoh."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import threading
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from api_stand_ins import InertJobs
from browser import CHROMIUM, chromium_on
from test_api_thresholds import StandInRegistry

with warnings.catch_warnings():  # starlette prefers httpx2 for its test client; httpx works
    warnings.filterwarnings("ignore", message=".*httpx.*deprecated")
    from fastapi.testclient import TestClient

from waiting import wait_until as _wait_until

from sara_app.api import ApiServer, ApiServerError, CellRegistry, create_app
from sara_app.api.app import merge_sections
from sara_app.api.jobs import LABEL_CHARS, whatif_label
from sara_app.api.registry import CYCLE_WINDOW
from sara_app.bus import keys
from sara_app.bus.codec import Decoded
from sara_app.bus.messages import ParamsAckMsg, ParamsMsg, RetireMsg, StatusMsg, VerdictMsg
from sara_app.bus.session import Bus, free_port
from sara_app.errors import SaraError
from sara_app.human.params import available_param_sets, load_param_set
from sara_app.safety.thresholds import threshold_set_names
from sara_app.scenario import (
    SHIPPED_SCENARIOS,
    load_scenario,
    parse_scenario,
    scenario_names,
    scenarios_dir,
)

VIEWER = "http://127.0.0.1:8080/"


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    """A private copy of the shipped scenarios: tests never write into the repository."""
    out = tmp_path / "scenarios"
    shutil.copytree(scenarios_dir(), out)
    return out


class Clock:
    def __init__(self) -> None:
        self.now_s = 1_000.0

    def __call__(self) -> float:
        return self.now_s


@pytest.fixture
def offline(folder: Path) -> Iterator[tuple[CellRegistry, TestClient, Clock]]:
    clock = Clock()
    reg = CellRegistry(None, clock=clock)
    with TestClient(create_app(reg, folder, viewer_url=VIEWER)) as client:
        yield reg, client, clock


def _status(cell: str, seq: int = 0, scenario: str = "demo") -> StatusMsg:
    return StatusMsg(seq=seq, stamp_s=1.0, cell=cell, state="running", scenario=scenario)


def _verdict(cell: str, seq: int, cycle_us: float, mode: str = "intended", **kw: Any) -> VerdictMsg:
    return VerdictMsg(
        seq=seq, stamp_s=1.0, cell=cell, safety_mode="ssm", mode=mode, cycle_time_us=cycle_us, **kw
    )


def _feed(reg: CellRegistry, cell: str, msg: Any, recv_s: float) -> None:
    kind = "status" if isinstance(msg, StatusMsg) else "verdict"
    reg.ingest(Decoded(keys.parse_key(keys.key(kind, cell)), msg, recv_s))  # type: ignore[arg-type]


def _base(folder: Path, name: str = "empty_cell") -> dict[str, Any]:
    return json.loads((folder / f"{name}.json").read_text())


def test_cells_from_status_and_verdicts(offline: tuple[CellRegistry, TestClient, Clock]) -> None:
    reg, client, clock = offline
    assert client.get("/api/cells").json() == []
    rng = np.random.default_rng(3)
    cycles = rng.lognormal(6.0, 0.5, size=CYCLE_WINDOW + 500)
    _feed(reg, "cell1", _status("cell1", scenario="punches"), clock.now_s)
    for i, c in enumerate(cycles):
        _feed(reg, "cell1", _verdict("cell1", i, float(c)), clock.now_s)
    last = _verdict(
        "cell1",
        len(cycles),
        250.0,
        mode="failsafe",
        min_distance_m=0.21,
        skeleton_age_s={"h1": 0.012},
        dropped={"out_of_order": 2},
        results={"pos": False, "vel": True},
    )
    _feed(reg, "cell1", last, clock.now_s)
    _feed(reg, "cell2", _verdict("cell2", 0, 100.0), clock.now_s)  # verdicts, never a status

    cells = client.get("/api/cells").json()
    assert [c["cell"] for c in cells] == ["cell1", "cell2"]
    c1, c2 = cells
    window = np.append(cycles, 250.0)[-CYCLE_WINDOW:]  # the rolling window: newest verdicts
    assert c1["cycle_time_p50_us"] == pytest.approx(np.percentile(window, 50))
    assert c1["cycle_time_p99_us"] == pytest.approx(np.percentile(window, 99))
    assert c1["cycle_window"] == CYCLE_WINDOW and c1["verdicts_received"] == len(cycles) + 1
    assert c1["online"] and c1["scenario"] == "punches" and c1["state"] == "running"
    assert c1["mode"] == "failsafe" and c1["safety_mode"] == "ssm"
    assert c1["min_distance_m"] == 0.21 and c1["skeleton_age_s"] == {"h1": 0.012}
    assert c1["dropped"] == {"out_of_order": 2} and c1["results"] == {"pos": False, "vel": True}
    assert not c2["online"] and c2["state"] is None and c2["mode"] is None  # never a status
    assert client.get("/api/cells/cell1").json() == c1

    clock.now_s += 0.6  # verdicts stopped (a hung worker): offline, mode unknown at once
    got = client.get("/api/cells/cell1").json()
    assert not got["online"] and got["mode"] is None
    assert got["verdict_age_s"] == pytest.approx(0.6)
    for _ in range(3):  # verdicts again, the status getting old
        clock.now_s += 0.4
        _feed(reg, "cell1", last, clock.now_s)
    assert client.get("/api/cells/cell1").json()["online"]  # status 1.8 s old
    clock.now_s += 0.25  # no status for 2.05 s (two heartbeats): offline
    got = client.get("/api/cells/cell1").json()
    assert not got["online"] and got["status_age_s"] == pytest.approx(2.05)
    assert got["mode"] is None
    _feed(reg, "cell1", _status("cell1", seq=1), clock.now_s)
    assert client.get("/api/cells/cell1").json()["online"]

    r = client.get("/api/cells/nope")
    assert r.status_code == 404 and "cell1, cell2" in r.json()["detail"]
    assert client.get("/api/cells/bad.name").status_code == 422
    assert client.get("/api/health").json() == {"ok": True, "bus": False, "cells": 2, "online": 1}


def test_scenarios_read_as_validated(
    offline: tuple[CellRegistry, TestClient, Clock], folder: Path
) -> None:
    _, client, _ = offline
    names = client.get("/api/scenarios").json()
    assert names == sorted(scenario_names(folder)) and "empty_cell" in names
    for name in names:
        assert client.get(f"/api/scenarios/{name}").json() == load_scenario(
            name, folder
        ).model_dump(mode="json")
    r = client.get("/api/scenarios/nope")
    assert r.status_code == 404 and "empty_cell" in r.json()["detail"]


def test_the_shipped_scenarios_are_the_repositorys() -> None:
    """``SHIPPED_SCENARIOS`` (never replaced by a client) names every scenario file the
    repository tracks."""
    import subprocess

    root = scenarios_dir().parent
    if not (root / ".git").exists():
        pytest.skip("not a git checkout")
    out = subprocess.run(["git", "-C", str(root), "ls-files", "scenarios"], capture_output=True,
                         text=True, check=True).stdout.split()  # fmt: skip
    assert {Path(p).stem for p in out} == set(SHIPPED_SCENARIOS)


def test_scenario_save_validates_and_never_overwrites_silently(
    offline: tuple[CellRegistry, TestClient, Clock], folder: Path
) -> None:
    _, client, _ = offline
    edit = _base(folder)
    edit["environment"][0]["center_m"] = [0.7, 0.1, 0.1]
    r = client.put("/api/scenarios/my_edit", json=edit)
    assert r.status_code == 200, r.text
    assert r.json() == {"name": "my_edit", "file": "my_edit.json", "overwritten": False}
    got = client.get("/api/scenarios/my_edit").json()
    assert got["name"] == "my_edit" and got["environment"][0]["center_m"] == [0.7, 0.1, 0.1]
    assert load_scenario(folder / "my_edit.json").environment[0].center_m == (0.7, 0.1, 0.1)

    shipped = (folder / "empty_cell.json").read_bytes()
    saved = (folder / "my_edit.json").read_bytes()
    edit["environment"][0]["center_m"] = [0.5, 0.0, 0.1]
    for name, why in (("empty_cell", "shipped"), ("my_edit", "overwrite=true")):
        r = client.put(f"/api/scenarios/{name}", json=edit)
        assert r.status_code == 409 and why in r.json()["detail"]
    assert (folder / "empty_cell.json").read_bytes() == shipped
    assert (folder / "my_edit.json").read_bytes() == saved
    r = client.put("/api/scenarios/empty_cell", params={"overwrite": "true"}, json=edit)
    assert r.status_code == 409 and "shipped" in r.json()["detail"]  # never, even so
    assert (folder / "empty_cell.json").read_bytes() == shipped
    r = client.put("/api/scenarios/my_edit", params={"overwrite": "true"}, json=edit)
    assert r.status_code == 200 and r.json()["overwritten"]
    assert client.get("/api/scenarios/my_edit").json()["environment"][0]["center_m"] == [
        0.5,
        0.0,
        0.1,
    ]

    before = sorted(p.name for p in folder.parent.rglob("*"))
    bad_cases = {
        "task.waypoints_rad.0": lambda s: s["task"]["waypoints_rad"][0].pop(),
        "shield.models": lambda s: s["shield"].update(models=["teleport"]),
        "environment.0.size_m": lambda s: s["environment"][0].update(size_m=[0.5, -1.0, 0.2]),
        "robot.name": lambda s: s["robot"].update(name="r2d2"),
        "humans.0: Input tag 'ghost'": lambda s: s.update(humans=[{"id": "h1", "type": "ghost"}]),
        "task.waypoints_rad.1": lambda s: s["task"]["waypoints_rad"][1].__setitem__(0, 9.0),
    }
    for field, mutate in bad_cases.items():
        sc = _base(folder)
        mutate(sc)
        r = client.put("/api/scenarios/bad_edit", json=sc)
        assert r.status_code == 422 and field in r.json()["detail"], (field, r.text)
    for name in ("a.b", "x" * 65, "..", "a b", "%2e%2e"):
        assert client.put(f"/api/scenarios/{name}", json=_base(folder)).status_code in (
            404,
            405,
            422,
        )
    assert sorted(p.name for p in folder.parent.rglob("*")) == before  # nothing written anywhere


def test_parameter_and_threshold_sets(offline: tuple[CellRegistry, TestClient, Clock]) -> None:
    _, client, _ = offline
    names = client.get("/api/params").json()
    assert "schepp2022_table1" in names and set(names) <= set(available_param_sets())
    for name in names:
        assert client.get(f"/api/params/{name}").json() == load_param_set(name).model_dump()
    for name in set(available_param_sets()) - set(names):  # files of another kind
        with pytest.raises(SaraError):
            load_param_set(name)
    r = client.get("/api/params/nope")
    assert r.status_code == 404 and "schepp2022_table1" in r.json()["detail"]
    assert client.get("/api/params/..").status_code in (404, 422)
    assert client.get("/api/thresholds").json() == list(threshold_set_names())
    for name in threshold_set_names():
        assert client.get(f"/api/thresholds/{name}").json()["name"] == name


def test_landing_page_docs_and_links(offline: tuple[CellRegistry, TestClient, Clock]) -> None:
    _, client, _ = offline
    page = client.get("/")
    assert page.status_code == 200 and "text/html" in page.headers["content-type"]
    assert 'src="app.js"' in page.text and 'href="/docs"' in page.text
    js = client.get("/app.js").text
    assert "/api/cells" in js and "/api/links" in js
    assert client.get("/style.css").status_code == 200
    assert client.get("/api/links").json() == {"viewer": VIEWER, "docs": "/docs"}
    assert client.get("/docs").status_code == 200
    paths = client.get("/openapi.json").json()["paths"]
    for p in (
        "/api/health",
        "/api/cells",
        "/api/cells/{cell}",
        "/api/cells/{cell}/scenario",
        "/api/scenarios/{name}",
        "/api/params/{name}",
        "/api/cells/{cell}/events",
    ):
        assert p in paths


def test_event_streams(offline: tuple[CellRegistry, TestClient, Clock]) -> None:
    reg, client, clock = offline
    _feed(reg, "cell1", _status("cell1"), clock.now_s)

    def events(url: str) -> list[Any]:
        with client.stream("GET", url) as r:
            assert r.headers["content-type"].startswith("text/event-stream")
            lines = [ln for ln in r.iter_lines() if ln.startswith("data: ")]
        return [json.loads(ln[6:]) for ln in lines]

    got = events("/api/cells/cell1/events?limit=3&interval_s=0.01")
    assert len(got) == 3 and all(e["cell"] == "cell1" and e["online"] for e in got)
    assert events("/api/cells/later/events?limit=1") == [
        {"cell": "later", "online": False, "known": False}
    ]
    assert [[c["cell"] for c in e] for e in events("/api/events?limit=2&interval_s=0.01")] == [
        ["cell1"],
        ["cell1"],
    ]
    assert client.get("/api/cells/a.b/events?limit=1").status_code == 422


def test_scenario_post_checks_before_sending(
    offline: tuple[CellRegistry, TestClient, Clock], folder: Path
) -> None:
    reg, client, clock = offline
    sc = _base(folder)
    sc["task"]["waypoints_rad"][0][3] = 5.0  # outside the Panda's joint 4 limits
    r = client.post("/api/cells/cell1/scenario", json=sc)
    assert r.status_code == 422 and "task.waypoints_rad.0" in r.json()["detail"]
    r = client.post("/api/cells/cell1/scenario", json=_base(folder))
    assert r.status_code == 404  # never seen on the bus
    _feed(reg, "cell1", _status("cell1"), clock.now_s)
    # its scenario is not announced: an unconfirmed edit cannot be compared with it
    r = client.post("/api/cells/cell1/scenario", json=_base(folder))
    assert r.status_code == 409 and r.json()["detail"]["needs_confirmation"]
    r = client.post("/api/cells/cell1/scenario?confirm=true", json=_base(folder))
    assert r.status_code == 504 and "no bus" in r.json()["detail"]

    # PATCH: merged onto the scenario file the cell reports ("demo" is not one), then validated
    r = client.patch("/api/cells/cell1/scenario", json={"shield": {"dt_s": 0.004}})
    assert r.status_code == 404 and "empty_cell" in r.json()["detail"]
    for changes, field in (
        ({"shield": {"dt_s": 1.0}}, "shield.dt_s"),
        ({"human_params": {"delay_s": -1.0}}, "delay_s"),
        ({"human_params": "nope"}, "human_params"),
        ({"limits": {"jerk": 2.0}}, "limits.jerk"),
        ({"colour": "red"}, "colour"),
    ):
        r = client.patch("/api/cells/cell1/scenario?base=empty_cell", json=changes)
        assert r.status_code == 422 and field in r.json()["detail"], (changes, r.text)
    r = client.patch(
        "/api/cells/cell1/scenario?base=empty_cell&confirm=true", json={"shield": {"dt_s": 0.002}}
    )
    assert r.status_code == 504  # valid: it would be sent


def test_a_refused_change_names_the_scenario_the_cell_runs(folder: Path) -> None:
    """A PATCH (or what-if) applied to the scenario the worker announced, with no ``base``:
    the refusal names that scenario, not "None"."""
    reg = StandInRegistry()
    reg.status("c1", "empty_cell")
    with TestClient(create_app(reg, folder)) as client:
        for url in ("/api/cells/c1/scenario", "/api/cells/c1/whatif"):
            r = client.request("PATCH" if url.endswith("scenario") else "POST", url,
                               json={"shield": {"dt_s": 1.0}})  # fmt: skip
            assert r.status_code == 422, r.text
            detail = r.json()["detail"]
            assert detail.startswith("scenario 'empty_cell' with the changes: shield.dt_s"), detail
            assert "None" not in detail


def test_a_whatif_job_is_labelled_with_its_changes(folder: Path) -> None:
    """The job list reads "c1: what if shield.dt_s = 0.002, human_params = "fast"", not the
    text of a Python list; long values and labels are shortened."""
    changes = {"shield": {"dt_s": 0.002}, "human_params": "fast"}
    want = 'c1: what if shield.dt_s = 0.002, human_params = "fast"'
    assert whatif_label("c1", changes) == want
    assert whatif_label("c1", {}) == "c1: what if (no changes)"
    long = whatif_label("c1", {"description": "x" * 500, "sim": {"seed": 1}})
    assert len(long) <= LABEL_CHARS and "..." in long
    reg = StandInRegistry()
    reg.status("c1", "empty_cell")
    with TestClient(create_app(reg, folder, jobs=InertJobs())) as client:
        assert client.post("/api/cells/c1/whatif", json=changes).status_code == 202
        assert [j["label"] for j in client.get("/api/jobs").json()] == [want]


def test_merge_sections() -> None:
    base = {"a": {"x": 1, "y": 2}, "b": [1, 2], "c": "s"}
    got = merge_sections(base, {"a": {"y": 3, "z": 4}, "b": [5], "c": {"k": 1}, "d": 0})
    assert got == {"a": {"x": 1, "y": 3, "z": 4}, "b": [5], "c": {"k": 1}, "d": 0}
    assert base == {"a": {"x": 1, "y": 2}, "b": [1, 2], "c": "s"}  # not modified
    deep = {"shield": {"mode": "pfl", "pfl": {"overrides": [1], "min_speed_scale": 0.02}}}
    got = merge_sections(deep, {"shield": {"pfl": {"min_speed_scale": 0.05}}})
    assert got == {"shield": {"mode": "pfl", "pfl": {"overrides": [1], "min_speed_scale": 0.05}}}
    assert deep["shield"]["pfl"]["min_speed_scale"] == 0.02  # not modified at any depth


# -- live: uvicorn + zenoh router + a fake worker ------------------------------------------------


class FakeWorker:
    """Publishes status and verdicts of ``cell``; answers params requests when ``answer``."""

    def __init__(self, port: int, cell: str, answer: bool) -> None:
        self.bus = Bus.client(port)
        self.cell, self.answer = cell, answer
        self.mode: str | None = None  # None: alternate intended / failsafe
        self.starting = False  # True: "starting" statuses and no verdicts (building the cell)
        self.dropped: dict[str, int] = {"superseded": 133088}  # normal: the newest is used
        self.extra: dict[str, Any] = {}  # further verdict fields (faults, intervened, ...)
        self.received: list[dict[str, Any]] = []
        self.confirmed: list[tuple[bool, str]] = []
        self._stop = threading.Event()
        self._status = self.bus.publisher(keys.status_key(cell))
        self._verdict = self.bus.publisher(keys.verdict_key(cell))
        self._ack = self.bus.publisher(keys.params_ack_key(cell))
        self._params = self.bus.subscribe(keys.params_key(cell), fifo=True) if answer else None
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        i = 0
        while not self._stop.wait(0.005):
            if i % 40 == 0:
                self._status.put(
                    StatusMsg(
                        seq=self._status.next_seq(),
                        stamp_s=time.time(),
                        cell=self.cell,
                        state="starting" if self.starting else "running",
                        scenario="empty_cell",
                        humans=["h1"],
                        detail="building the cell: compiling (2 s)" if self.starting else "",
                    )
                )
            if self.starting:
                i += 1
                continue
            mode = self.mode or ("failsafe" if i % 2 else "intended")
            self._verdict.put(
                _verdict(
                    self.cell,
                    self._verdict.next_seq(),
                    300.0 + i % 7,
                    mode=mode,
                    min_distance_m=0.5,
                    skeleton_age_s={"h1": 0.01},
                    dropped=self.dropped,
                    **self.extra,
                )
            )
            i += 1
            if self._params is not None:
                for d in self._params.drain().messages:
                    self._answer(d.msg)  # type: ignore[arg-type]

    def _answer(self, msg: ParamsMsg) -> None:
        self.received.append(msg.scenario)
        self.confirmed.append((msg.confirm, msg.user))
        boxes = [b["name"] for b in msg.scenario.get("environment", [])]
        ok = "forbidden" not in boxes
        reason = "" if ok else "environment: box 'forbidden' blocks the task"
        self._ack.put(
            ParamsAckMsg(
                seq=self._ack.next_seq(),
                stamp_s=time.time(),
                request_id=msg.request_id,
                accepted=ok,
                reason=reason,
            )
        )

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self.bus.close()


def test_live_cell_and_scenario_round_trip(folder: Path) -> None:
    port = free_port()
    with Bus.router(port), CellRegistry.connect(port) as reg:
        server = ApiServer(create_app(reg, folder, viewer_url=VIEWER), port=0)
        url = server.start()
        assert url.startswith("http://127.0.0.1:") and not url.endswith(":0/")
        worker = FakeWorker(port, "cell1", answer=True)
        mute = FakeWorker(port, "cell2", answer=False)
        try:
            # a taken port is seen as uvicorn's exit, not waited out to the start timeout
            with pytest.raises(ApiServerError, match=r"did not start.*exited at start-up"):
                ApiServer(create_app(reg, folder), port=int(url.rsplit(":", 1)[1][:-1])).start()
            with httpx.Client(base_url=url, timeout=10) as http:

                def both_online() -> list[Any]:
                    cells = http.get("api/cells").json()
                    on = [c for c in cells if c["online"] and c["verdicts_received"] > 5]
                    return cells if len(on) == 2 else []

                c1 = _wait_until(both_online)[0]
                assert c1["cell"] == "cell1" and c1["scenario"] == "empty_cell"
                assert c1["mode"] in ("intended", "failsafe") and c1["min_distance_m"] == 0.5
                assert 300.0 <= c1["cycle_time_p50_us"] <= c1["cycle_time_p99_us"] <= 306.0

                sc = _base(folder)
                sc["environment"][0]["center_m"] = [0.7, 0.0, 0.1]
                # this stand-in worker announces no scenario: every edit is unconfirmed until
                # confirmed (the comparison with what the cell runs is tested with a real one)
                r = http.post("api/cells/cell1/scenario", json=sc)
                assert r.status_code == 409 and r.json()["detail"]["needs_confirmation"]
                assert len(worker.received) == 0
                r = http.post("api/cells/cell1/scenario?confirm=true", json=sc)
                assert r.status_code == 200, r.text
                assert r.json()["accepted"]
                assert worker.received[-1] == parse_scenario(sc).model_dump(mode="json")
                assert worker.received[-1]["environment"][0]["center_m"] == [0.7, 0.0, 0.1]
                assert worker.confirmed[-1] == (True, "local")  # the worker checks it too
                sc["environment"][0]["name"] = "forbidden"
                r = http.post("api/cells/cell1/scenario?confirm=true", json=sc)
                assert r.status_code == 409 and "blocks the task" in r.json()["detail"]
                assert len(worker.received) == 2
                r = http.patch(
                    "api/cells/cell1/scenario?confirm=true",
                    json={"shield": {"skeleton_timeout_s": 0.1}, "human_params": {"delay_s": 0.05}},
                )
                assert r.status_code == 200, r.text
                # a PATCH builds on what the cell runs: the last scenario it accepted
                want = dict(worker.received[0])
                assert want["environment"][0]["center_m"] == [0.7, 0.0, 0.1]
                got = worker.received[-1]
                assert got == r.json()["applied"]
                assert got["shield"] == {**want["shield"], "skeleton_timeout_s": 0.1}
                named = load_param_set(want["human_params"]).model_dump(mode="json")
                assert got["human_params"] == {
                    **named,
                    "name": want["human_params"] + "_edited",
                    "delay_s": 0.05,
                }
                for k in set(want) - {"shield", "human_params"}:
                    assert got[k] == want[k], k
                r = http.post(
                    "api/cells/cell2/scenario",
                    params={"timeout_s": 0.5, "confirm": "true"},
                    json=sc,
                )
                assert r.status_code == 504 and "did not answer" in r.json()["detail"]
                with http.stream("GET", "api/cells/cell1/events?limit=2&interval_s=0.05") as s:
                    data = [json.loads(x[6:]) for x in s.iter_lines() if x.startswith("data: ")]
                assert [d["cell"] for d in data] == ["cell1", "cell1"]
        finally:
            worker.close()
            mute.close()
            server.stop()
        with pytest.raises(httpx.TransportError):
            httpx.get(url + "api/health", timeout=1)


# -- the landing page in headless chromium -------------------------------------------------------


@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} is absent")
def test_landing_page_asks_for_its_links_again_until_they_come(folder: Path) -> None:
    """The first ``/api/links`` fails (a service still starting, a proxy's hiccup): the page
    asks again and shows the 3D view's link (it asked once and stayed without it)."""
    from fastapi import Request, Response

    app = create_app(StandInRegistry(), folder, viewer_url=VIEWER)
    refused: list[int] = []

    @app.middleware("http")
    async def _refuse_the_first_links(request: Request, call_next: Any) -> Response:
        if request.url.path == "/api/links" and len(refused) < 2:
            refused.append(1)
            return Response("starting", status_code=503)
        return await call_next(request)

    server = ApiServer(app, port=0)
    url = server.start()
    try:
        with chromium_on(url) as page:
            link = "document.getElementById('viewer-link')"
            assert _wait_until(lambda: page.eval(f"{link}.href") == VIEWER, 20.0), refused
            assert page.eval(f"{link}.hidden") is False
        assert len(refused) == 2
    finally:
        server.stop()


@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} is absent")
def test_landing_page_shows_live_status_in_chromium(folder: Path, tmp_path: Path) -> None:
    port = free_port()
    with Bus.router(port), CellRegistry.connect(port) as reg:
        server = ApiServer(create_app(reg, folder, viewer_url=VIEWER), port=0)
        url = server.start()
        worker = FakeWorker(port, "cell1", answer=False)
        worker.mode = "intended"
        stack = contextlib.ExitStack()
        try:
            page = stack.enter_context(chromium_on(url))
            card = "document.querySelector('article[data-cell=\"cell1\"]')"

            def mode() -> str:
                return str(page.eval(f"{card} ? {card}.dataset.mode : ''") or "")  # type: ignore[union-attr]

            assert _wait_until(lambda: mode() == "intended", 20.0)
            page.eval("window.__sameLoad = 1")  # survives only if the page is never reloaded
            assert page.eval(f"{card}.textContent").count("empty_cell") == 1
            # the links come from their own request, which may answer after the cards' (a CI
            # mirror read the placeholder "#")
            link = "document.getElementById('viewer-link').href"
            assert _wait_until(lambda: page.eval(link) == VIEWER, 20.0), page.eval(link)
            assert page.eval(f"{card}.dataset.safetyMode") == "ssm"
            text = str(page.eval(f"{card}.textContent"))  # superseded is normal, not a drop
            assert "droppednone" in text and "133088" not in text, text
            assert page.eval(f"{card}.querySelector('h2 .tag').textContent") == "SSM"
            hrefs = page.eval(f"[...{card}.querySelectorAll('.more a')].map(a => a.href)")
            assert hrefs == [
                url + "api/cells/cell1/thresholds",
                url + "api/cells/cell1/thresholds/audit",
            ]
            green = page.eval(f"getComputedStyle({card}).borderLeftColor")
            # the verdict in words, one state after the other (the API's sentence)
            words = f"{card}.querySelector('.verdict')"
            states = [
                ("intended", {}, "moving", "Moving on its verified path"),
                ("intended", {"intervened": True, "speed_scale": 0.4, "blocking": ["h1 r_hand"]},
                 "slowed", "slowed to 40 % of its speed by SSM: h1's right hand, 0.50 m"),
                ("failsafe", {"blocking": ["h1 head"]}, "braking",
                 "Braking along the verified stop (SSM): h1's head, 0.50 m"),
                ("fault", {"faults": ["h1: no skeleton for 0.12 s"]}, "fault",
                 "Fault for 0 s: h1: no skeleton for 0.12 s. The robot holds its verified stop"),
            ]  # fmt: skip
            for mode_, extra, state, text in states:
                worker.mode, worker.extra = mode_, extra
                assert _wait_until(lambda s=state: page.eval(f"{words}.dataset.state") == s, 10.0)
                assert text in str(page.eval(f"{words}.textContent")), page.eval(
                    words + ".textContent"
                )
                shots = os.environ.get("SARA_SCREENSHOT_DIR")
                if shots:  # for looking at them by hand (docs/images)
                    from PIL import Image

                    Image.fromarray(page.screenshot().astype("uint8")).save(
                        Path(shots) / f"landing-{state}.png"
                    )
            worker.extra = {}
            worker.mode = "fault"
            assert _wait_until(lambda: mode() == "fault", 10.0)
            red = page.eval(f"getComputedStyle({card}).borderLeftColor")
            assert page.eval("window.__sameLoad") == 1
            rgb = [[int(x) for x in c[c.index("(") + 1 : -1].split(",")[:3]] for c in (green, red)]
            assert rgb[0][1] > rgb[0][0] and rgb[1][0] > rgb[1][1]  # green, then red
            worker.close()  # no status any more: offline after 3 s, still without a reload
            assert _wait_until(lambda: mode() == "offline", 10.0)
            assert page.eval("window.__sameLoad") == 1
        finally:
            stack.close()
            worker.close()
            server.stop()


def test_server_stop_ends_open_event_streams(folder: Path) -> None:
    reg = CellRegistry(None)
    server = ApiServer(create_app(reg, folder), port=0)
    url = server.start()
    got: list[str] = []
    opened = threading.Event()

    def listen() -> None:
        with httpx.stream("GET", url + "api/events?interval_s=0.05", timeout=30) as r:
            for line in r.iter_lines():
                got.append(line)
                opened.set()

    reader = threading.Thread(target=listen, daemon=True)
    reader.start()
    assert opened.wait(10)
    server.stop()  # raises ApiServerError if uvicorn's thread is still serving the stream
    reader.join(10)
    assert not reader.is_alive() and "data: []" in got
    url = server.start()  # can be started again, and its streams flow again
    with httpx.stream("GET", url + "api/events?interval_s=0.01&limit=2", timeout=10) as r:
        assert [x for x in r.iter_lines() if x.startswith("data:")] == ["data: []"] * 2
    server.stop()


def test_edit_over_the_api_reaches_the_real_worker(folder: Path, tmp_path: Path) -> None:
    """The project's cell worker (in a thread here) applies a scenario sent over the API: its
    status then reports the new scenario, and the verdicts keep coming. The worker records
    what it answered in the API's audit log, and so also what another editor on the bus sent
    it, which the API never saw."""
    from sara_app.runtime.worker import CellWorker

    port = free_port()
    audit = tmp_path / "audit.sqlite"
    with Bus.router(port), CellRegistry.connect(port) as reg, Bus.client(port) as wbus:
        worker = CellWorker("cellw", load_scenario("empty_cell", folder), wbus, status_hz=10.0,
                            audit=audit)  # fmt: skip
        thread = threading.Thread(target=worker.run, daemon=True)
        thread.start()
        client = TestClient(create_app(reg, folder, audit=audit))
        try:

            def snap() -> dict[str, Any]:
                return dict(client.get("/api/cells/cellw").json())

            _wait_until(lambda: snap().get("online"), 20.0)
            _wait_until(lambda: reg.applied_scenario("cellw") is not None, 10.0)
            sc = _base(folder)
            sc["name"] = "moved_table"
            sc["environment"][0]["center_m"] = [0.8, 0.0, 0.1]
            # moving the bench loosens what the verdict assumes: refused, recorded, unapplied
            r = client.post("/api/cells/cellw/scenario", json=sc)
            assert r.status_code == 409, r.text
            detail = r.json()["detail"]
            assert detail["needs_confirmation"] and "'bench' center_m" in detail["loosens"][0]
            assert worker.cell.scenario.environment[0].center_m != (0.8, 0.0, 0.1)
            r = client.post("/api/cells/cellw/scenario", params={"confirm": "true"}, json=sc)
            assert r.status_code == 200, r.text
            assert r.json()["loosens"] == detail["loosens"]
            rows = client.get("/api/cells/cellw/assumptions/audit").json()
            assert [(x["outcome"], x["confirmed"], x["user"]) for x in rows] == [
                ("applied", True, "local"),
                ("refused", False, "local"),
            ]
            assert rows[0]["changes"] == detail["loosens"] and rows[1]["id"] == detail["audit_id"]
            cell = _wait_until(lambda: (c := snap())["scenario"] == "moved_table" and c, 10.0)
            assert worker.cell.scenario.environment[0].center_m == (0.8, 0.0, 0.1)
            n = cell["verdicts_received"]
            assert _wait_until(lambda: snap()["verdicts_received"] > n)
            with Bus.client(port) as script:  # another editor on the bus, not the API
                _the_worker_audits_every_editor(client, script, worker)
        finally:
            worker.stop_event.set()
            thread.join(5)


def _the_worker_audits_every_editor(client: TestClient, bus: Bus, worker: Any) -> None:
    """The worker's own record (``GET .../worker/audit``): the API's confirmed edit, then a
    script on the bus: a loosening it did not confirm (refused), a tightening (applied, the
    checksum in force after it), a retirement of nobody (refused); newest first."""

    def rows(n: int) -> list[dict[str, Any]]:
        return _wait_until(
            lambda: len(r := client.get("/api/cells/cellw/worker/audit").json()) >= n and r, 10.0
        )

    first = rows(1)
    assert [(x["request"], x["outcome"], x["confirmed"], x["user"]) for x in first] == [
        ("edit", "applied", True, "local")
    ]
    assert first[0]["checksum"] == worker.cell.checksum
    assert first[0]["reason"].startswith("confirmed loosening: environment box 'bench' center_m")
    edits = bus.publisher(keys.params_key("cellw"))
    loosened = worker.cell.scenario.model_dump(mode="json")
    loosened["environment"] = []  # the bench removed, unconfirmed
    tightened = worker.cell.scenario.model_dump(mode="json")
    tightened["inputs"]["max_people"] = 3
    for rid, sc in (("script-1", loosened), ("script-2", tightened)):
        seq = time.time_ns() // 1000  # after the API's numbering on the key (time-based too)
        edits.put(ParamsMsg(seq=seq, stamp_s=time.time(), request_id=rid, scenario=sc,
                            user="script"))  # fmt: skip
        rows(len(first) + int(rid[-1]))  # in order: one answered before the next is sent
    retire = bus.publisher(keys.retire_key("cellw"))
    retire.put(RetireMsg(seq=0, stamp_s=time.time(), request_id="script-3", human_id="nobody",
                         user="script"))  # fmt: skip
    got = rows(4)[:3]
    assert [(x["request"], x["request_id"], x["user"], x["outcome"]) for x in got] == [
        ("retire", "script-3", "script", "refused"),
        ("edit", "script-2", "script", "applied"),
        ("edit", "script-1", "script", "refused"),
    ]
    assert "loosens" in got[2]["reason"] and got[1]["checksum"] == worker.cell.checksum
    assert worker.cell.scenario.inputs.max_people == 3 and worker.cell.scenario.environment


def test_concurrent_patches_are_serialised_and_none_is_lost(folder: Path) -> None:
    """Eight PATCHes sent at once, each changing another field: every one is applied by the
    real worker, in turn, each on the scenario its predecessor made it run."""
    from concurrent.futures import ThreadPoolExecutor

    from worker_thread import running_worker

    port = free_port()
    first = load_scenario("empty_cell", folder)
    with Bus.router(port), CellRegistry.connect(port) as reg, Bus.client(port) as wbus, \
            running_worker("cellp", first, wbus, status_hz=10.0) as worker:  # fmt: skip
        client = TestClient(create_app(reg, folder))
        _wait_until(lambda: client.get("/api/cells/cellp").json().get("online"), 20.0)
        _wait_until(lambda: reg.applied_scenario("cellp") is not None, 10.0)
        edits = [{"description": "serial"}] + [
            {"shield": {k: v}}
            for k, v in [("models", ["pos", "vel", "acc"]), ("max_interval_s", 0.03),
                         ("tracking_tol_rad", 0.006), ("skeleton_timeout_s", 0.15)]  # fmt: skip
        ] + [{"inputs": {"max_people": 7}}, {"inputs": {"tracker_timeout_s": 0.3}},
             {"sim": {"seed": 5}}]  # fmt: skip

        def patch(changes: dict[str, Any]) -> int:  # some loosen (confirmed; not the point)
            r = client.patch("/api/cells/cellp/scenario?confirm=true", json=changes)
            return r.status_code

        with ThreadPoolExecutor(8) as pool:
            codes = list(pool.map(patch, edits))
        assert codes == [200] * len(edits)
        sc = worker.cell.scenario
        assert sc.description == "serial" and sc.sim.seed == 5
        assert (sc.shield.models, sc.shield.max_interval_s) == (["pos", "vel", "acc"], 0.03)
        assert (sc.shield.tracking_tol_rad, sc.shield.skeleton_timeout_s) == (0.006, 0.15)
        assert (sc.inputs.max_people, sc.inputs.tracker_timeout_s) == (7, 0.3)


# -- the API docs without internet ---------------------------------------------------------------


def test_docs_load_their_assets_from_the_service(offline) -> None:
    """``/docs`` references Swagger UI's files on this service (installed package), no CDN."""
    _, client, _ = offline
    html = client.get("/docs").text
    assert "/docs-assets/swagger-ui-bundle.js" in html and "/docs-assets/swagger-ui.css" in html
    assert "cdn." not in html and "https://" not in html.replace("https://swagger.io", "")
    js = client.get("/docs-assets/swagger-ui-bundle.js")
    assert js.status_code == 200 and len(js.content) > 100_000
    assert client.get("/docs-assets/swagger-ui.css").status_code == 200
    assert client.get("/docs/oauth2-redirect").status_code == 200
    redoc = client.get("/redoc").text
    assert "/docs-assets/redoc.standalone.js" in redoc and "fonts.googleapis" not in redoc


@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} is absent")
def test_docs_list_the_routes_in_chromium(folder: Path) -> None:
    """In a browser that cannot reach the internet (this machine), /docs renders every route."""
    port = free_port()
    with Bus.router(port), CellRegistry.connect(port) as reg:
        server = ApiServer(create_app(reg, folder, viewer_url=VIEWER), port=0)
        url = server.start()
        try:
            with chromium_on(url + "docs") as page:
                assert _wait_until(
                    lambda: "/api/health" in str(page.eval("document.body.innerText")), 30.0
                )
                text = str(page.eval("document.body.innerText"))
        finally:
            server.stop()
    for route in ("/api/cells/{cell}/scenario", "/api/cells/{cell}/thresholds", "/api/params"):
        assert route in text, route


@pytest.mark.skipif(not Path(CHROMIUM).exists(), reason=f"{CHROMIUM} is absent")
def test_landing_page_says_a_cell_is_starting(folder: Path) -> None:
    """A worker still building its cell (no verdict yet) shows as "starting", with what it
    does, not as offline or as a cell with no recent verdict."""
    port = free_port()
    with Bus.router(port), CellRegistry.connect(port) as reg:
        server = ApiServer(create_app(reg, folder, viewer_url=VIEWER), port=0)
        url = server.start()
        worker = FakeWorker(port, "cell1", answer=False)
        worker.starting = True
        try:
            with chromium_on(url) as page:
                card = "document.querySelector('article[data-cell=\"cell1\"]')"
                assert _wait_until(
                    lambda: page.eval(f"{card} ? {card}.dataset.mode : ''") == "starting", 20.0
                )
                text = str(page.eval(f"{card}.textContent"))
            assert "building the cell: compiling (2 s)" in text
            snap = reg.cell("cell1")
            assert snap is not None and snap["state"] == "starting" and snap["starting"]
            assert not snap["online"]  # online means running and reporting
        finally:
            worker.close()
            server.stop()


def test_a_status_stamped_in_the_future_blinds_nothing() -> None:
    """Hostile controller-side probe, 2026-11-30: one ``controller/status`` stamped an hour
    ahead and numbered 2e9 was kept, and every real status after it was refused as out of
    order for that hour (the cell's controller shown offline). The registry now refuses a
    message stamped ahead of its clock, as the worker and the controller do."""
    from sara_app.bus.messages import ControllerStatusMsg

    def status(seq: int, stamp: float, received: int) -> ControllerStatusMsg:
        return ControllerStatusMsg(
            seq=seq, stamp_s=stamp, cell="cell1", commands_received=received, commands_lost=0,
            commands_late=0, commands_expired=0, commands_refused=0, braking_events=0,
            worker_runs=1, braking=False,
        )  # fmt: skip

    port = free_port()
    with Bus.router(port), CellRegistry.connect(port) as reg, Bus.client(port) as bus:
        pub = bus.publisher(keys.controller_status_key("cell1"))
        _wait_until(pub.has_subscribers)
        pub.put(status(2_000_000_000, time.time() + 3600.0, 10**15))
        for seq in range(1, 30):
            pub.put(status(seq, time.time(), seq))
            time.sleep(0.05)
            reg.poll()
        c = reg._cells["cell1"].controller
        assert c is not None and c.commands_received == 29
