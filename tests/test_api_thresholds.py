"""The threshold editor's REST routes: effective table, validated PUT (422 invalid, 409 above the
source value without confirmation, 200 when the worker accepts, 502 refused, 504 no answer),
every outcome in the audit log, edits accumulate on the scenario the cell runs, concurrent PUTs
serialised, OpenAPI. The worker here is a stand-in for ``request_params``; the real worker over
zenoh is in ``test_live_edit.py``."""

from __future__ import annotations

import json
import shutil
import threading
import time
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message=".*httpx.*deprecated")
    from fastapi.testclient import TestClient

from sara_app.api import CellRegistry, create_app
from sara_app.api.registry import ParamsAnswer
from sara_app.api.thresholds import NOT_ANNOUNCED
from sara_app.bus import keys
from sara_app.bus.codec import Decoded
from sara_app.bus.messages import ScenarioStateMsg, StatusMsg
from sara_app.errors import WorkerTimeoutError
from sara_app.ops.audit import AuditLog
from sara_app.safety.thresholds import load_thresholds
from sara_app.scenario import load_scenario, parse_scenario, scenarios_dir

SEED = load_thresholds("thresholds_thumm2024")
HAND = {"region": "hand", "contact": "constrained", "shape": "blunt"}


class StandInRegistry(CellRegistry):
    """No bus: ``request_params`` answers as ``answer`` says (accept / refuse / silent)."""

    def __init__(self) -> None:
        super().__init__(None)
        self.answer = "accept"
        self.delay_s = 0.0
        self.received: list[dict[str, Any]] = []
        self.confirmed: list[bool] = []

    def request_params(
        self,
        cell: str,
        scenario: dict[str, Any],
        timeout_s: float = 3.0,
        confirm: bool = False,
        user: str = "",
    ) -> ParamsAnswer:
        time.sleep(self.delay_s)
        self.confirmed.append(confirm)
        if self.answer == "silent":
            raise WorkerTimeoutError(f"the worker of cell {cell!r} did not answer")
        self.received.append(scenario)
        if self.answer == "refuse":
            return ParamsAnswer("r", False, "robot busy")
        self._remember(cell, scenario)
        return ParamsAnswer("r", True, "")

    def status(
        self, cell: str, scenario: str, started_s: float = 100.0, announce: bool = True
    ) -> None:
        """A worker's heartbeat: its status and (``announce``, as a real worker does with each
        heartbeat) the scenario it runs: ``scenario`` from the shipped folder."""
        now = time.time()
        msg = StatusMsg(
            seq=int(now * 1e6),
            stamp_s=now,
            cell=cell,
            state="running",
            scenario=scenario,
            uptime_s=now - started_s,
        )
        self.ingest(Decoded(keys.parse_key(keys.status_key(cell)), msg, now))
        if announce:
            sc = load_scenario(scenario).model_dump(mode="json")
            ann = ScenarioStateMsg(seq=int(now * 1e6), stamp_s=now, cell=cell, revision=0,
                                   scenario=sc)  # fmt: skip
            self.ingest(Decoded(keys.parse_key(keys.scenario_key(cell)), ann, now))


@pytest.fixture
def api(tmp_path: Path) -> Iterator[tuple[StandInRegistry, TestClient, AuditLog]]:
    folder = tmp_path / "scenarios"
    shutil.copytree(scenarios_dir(), folder)
    reg = StandInRegistry()
    reg.status("c1", "empty_cell")
    audit = AuditLog(tmp_path / "audit.sqlite")
    with TestClient(create_app(reg, folder, audit=audit)) as client:
        yield reg, client, audit


def _row(table: dict[str, Any], region: str, contact: str, shape: str) -> dict[str, Any]:
    return next(
        r
        for r in table["entries"]
        if (r["region"], r["contact"], r["shape"]) == (region, contact, shape)
    )


def test_effective_table(api: tuple[StandInRegistry, TestClient, AuditLog]) -> None:
    _, client, _ = api
    t = client.get("/api/cells/c1/thresholds").json()
    assert t["cell"] == "c1" and t["scenario"] == "empty_cell" and t["state"] == "running"
    assert t["thresholds"] == "thresholds_thumm2024" and len(t["entries"]) == 40
    assert t["sources"] == SEED.sources
    r = _row(t, "hand", "constrained", "blunt")
    assert r["energy_J"] == r["source_energy_J"] == SEED.energy_J("hand", "constrained", "blunt")
    assert r["source_key"] == "iso15066" and not r["overridden"]
    assert r["iso_reference"][0]["iso_region"] == "hand"
    note = t["iso_reference_note"]  # cites the standard and the paper, no file outside the repo
    assert "ISO/TS 15066:2016" in note and "Annex A" in note
    assert "Thumm" in note and "A General Safety Framework" in note and "2024" in note
    assert ".md" not in note and "shared/" not in note
    assert client.get("/api/cells/nope/thresholds").status_code == 404
    assert client.get("/api/cells/bad.name/thresholds").status_code == 422


def test_put_outcomes_and_audit(api: tuple[StandInRegistry, TestClient, AuditLog]) -> None:
    reg, client, audit = api
    src = SEED.limit("hand", "constrained", "blunt")
    # below the source: applied
    r = client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": 0.1, "user": "ana"})
    assert r.status_code == 200, r.text
    body = r.json()
    assert body["accepted"] and body["edit"]["old_energy_J"] == src.energy_J
    # one user per request: the request's (no token here: "local"), never the body's "ana"
    assert body["audit"]["outcome"] == "applied" and body["audit"]["user"] == "local"
    assert client.get("/api/requests/audit").json()[0]["user"] == "local"
    ov = reg.received[-1]["shield"]["pfl"]["overrides"]
    assert ov == [{**HAND, "energy_J": 0.1}]
    parse_scenario(reg.received[-1])  # a whole, valid scenario was sent
    # above the source without confirmation: 409 naming the source, nothing sent
    r = client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": 0.5})
    assert r.status_code == 409
    d = r.json()["detail"]
    assert d["needs_confirmation"] and d["source_key"] == "iso15066"
    assert d["source_energy_J"] == src.energy_J and "0.12 J" in d["message"]
    assert isinstance(d["audit_id"], int) and len(reg.received) == 1
    # confirmed: applied, and the first edit's base is the applied scenario
    r = client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": 0.5, "confirm": True})
    assert r.status_code == 200 and r.json()["edit"]["old_energy_J"] == 0.1
    assert r.json()["audit"]["exceeds_source"] and r.json()["audit"]["confirmed"]
    # invalid values and names: 422 with the valid range / choices
    for bad, want in (
        ({**HAND, "energy_J": 0.0}, "> 0 J"),
        ({**HAND, "energy_J": -2}, "> 0 J"),
        ({**HAND, "region": "elbow", "energy_J": 0.1}, "valid choices"),
    ):
        r = client.put("/api/cells/c1/thresholds", json=bad)
        assert r.status_code == 422 and want in r.json()["detail"], r.text
    nan = json.dumps({**HAND, "energy_J": float("nan")})  # NaN token, as Python writes it
    r = client.put(
        "/api/cells/c1/thresholds", content=nan, headers={"content-type": "application/json"}
    )
    assert r.status_code == 422 and "nan" in r.json()["detail"]
    # the worker refuses / does not answer
    reg.answer = "refuse"
    r = client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": 0.11})
    assert r.status_code == 502 and "robot busy" in r.json()["detail"]
    reg.answer = "silent"
    r = client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": 0.11})
    assert r.status_code == 504
    rows = client.get("/api/cells/c1/thresholds/audit", params={"limit": 100}).json()
    assert [x["outcome"] for x in rows] == [
        "no_answer",
        "refused",
        "refused",
        "refused",
        "refused",
        "refused",
        "applied",
        "refused",
        "applied",
    ]
    assert rows[-2]["id"] == d["audit_id"] and "confirm" in rows[-2]["reason"]
    assert [x["id"] for x in rows] == sorted((x["id"] for x in rows), reverse=True)
    assert client.get("/api/cells/c1/thresholds/audit", params={"limit": 2}).json() == rows[:2]
    assert rows == [e.to_dict() for e in audit.entries("c1", 100)]
    assert client.get("/api/cells/c1/thresholds/audit", params={"limit": 0}).status_code == 422
    # the table shows the value in force (the last accepted edit)
    t = client.get("/api/cells/c1/thresholds").json()
    assert t["state"] == "running"
    r0 = _row(t, "hand", "constrained", "blunt")
    assert r0["energy_J"] == 0.5 and r0["overridden"] and r0["exceeds_source"]


def test_back_to_source_removes_the_override(
    api: tuple[StandInRegistry, TestClient, AuditLog],
) -> None:
    reg, client, _ = api
    head = {"region": "head", "contact": "unconstrained", "shape": "edge"}
    assert client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": 0.1}).is_success
    assert client.put("/api/cells/c1/thresholds", json={**head, "energy_J": 0.05}).is_success
    assert len(reg.received[-1]["shield"]["pfl"]["overrides"]) == 2
    src = SEED.energy_J("hand", "constrained", "blunt")
    r = client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": src})
    assert r.status_code == 200 and r.json()["edit"]["removes_override"]
    assert reg.received[-1]["shield"]["pfl"]["overrides"] == [{**head, "energy_J": 0.05}]


def test_the_table_is_the_running_workers_or_none_while_it_has_not_said(
    api: tuple[StandInRegistry, TestClient, AuditLog],
) -> None:
    """After an edit the table is the edited scenario; a restarted worker (a new start time)
    that has not announced what it runs yet gives no values (its saved edits may differ from
    the file); once it has, its scenario."""
    reg, client, _ = api
    assert client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": 0.1}).is_success
    reg.status("c1", "empty_cell", announce=False)  # same worker, same scenario: the edit
    t = client.get("/api/cells/c1/thresholds").json()
    assert t["state"] == "running" and _row(t, "hand", "constrained", "blunt")["overridden"]
    time.sleep(0.1)  # a worker restarts after the last announcement of the previous one
    reg.status("c1", "empty_cell", started_s=time.time(), announce=False)  # restarted
    t = client.get("/api/cells/c1/thresholds").json()
    assert t == {"cell": "c1", "state": "starting", "detail": NOT_ANNOUNCED}
    r = client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": 0.1})
    assert r.status_code == 409 and "not announced" in r.json()["detail"]
    reg.status("c1", "punches", started_s=time.time() - 1.0)  # it says what it runs
    t = client.get("/api/cells/c1/thresholds").json()
    assert t["state"] == "running" and t["scenario"] == "punches"
    assert not _row(t, "hand", "constrained", "blunt")["overridden"]


def test_a_new_service_knows_nothing_until_the_worker_announces(tmp_path: Path) -> None:
    """``serve`` restarted with a saved edit: the API must not answer the file's values while
    the worker runs the saved ones."""
    reg = StandInRegistry()
    reg.status("c1", "punches", announce=False)
    with TestClient(create_app(reg, tmp_path, audit=AuditLog(tmp_path / "a.sqlite"))) as client:
        assert client.get("/api/cells/c1/thresholds").json()["state"] == "starting"
        saved = load_scenario("punches").model_dump(mode="json")
        saved["shield"]["pfl"]["overrides"] = [{**HAND, "energy_J": 0.05}]
        now = time.time()
        ann = ScenarioStateMsg(seq=1, stamp_s=now, cell="c1", revision=3, scenario=saved)
        reg.ingest(Decoded(keys.parse_key(keys.scenario_key("c1")), ann, now))
        t = client.get("/api/cells/c1/thresholds").json()
        assert _row(t, "hand", "constrained", "blunt")["energy_J"] == 0.05


def test_concurrent_puts_are_serialised(api: tuple[StandInRegistry, TestClient, AuditLog]) -> None:
    reg, client, audit = api
    reg.delay_s = 0.02
    shapes = ("blunt", "wedge", "edge", "sheet")
    answers: list[int] = []

    def put(shape: str) -> None:
        body = {"region": "upper_arm", "contact": "unconstrained", "shape": shape}
        value = SEED.energy_J("upper_arm", "unconstrained", shape) * 0.5
        r = client.put("/api/cells/c1/thresholds", json={**body, "energy_J": value})
        answers.append(r.status_code)

    threads = [threading.Thread(target=put, args=(s,)) for s in shapes]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert answers == [200] * 4
    final = {o["shape"] for o in reg.received[-1]["shield"]["pfl"]["overrides"]}
    assert final == set(shapes)  # no edit lost to a concurrent one
    assert len(audit.entries("c1")) == 4


def test_openapi_documents_the_routes(api: tuple[StandInRegistry, TestClient, AuditLog]) -> None:
    _, client, _ = api
    spec = client.get("/openapi.json").json()
    assert {"get", "put"} <= set(spec["paths"]["/api/cells/{cell}/thresholds"])
    assert "get" in spec["paths"]["/api/cells/{cell}/thresholds/audit"]
    body = spec["components"]["schemas"]["ThresholdEditBody"]["properties"]
    assert body["region"]["enum"] == ["hand", "lower_arm", "upper_arm", "torso_legs", "head"]
    assert body["confirm"]["default"] is False and body["user"]["default"] == "unknown"
    put = spec["paths"]["/api/cells/{cell}/thresholds"]["put"]
    assert {"200", "409", "422", "502", "504"} <= set(put["responses"])


def test_audit_log_opened_lazily_at_its_default_place(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SARA_APP_DATA", str(tmp_path / "data"))
    reg = StandInRegistry()
    reg.status("c1", "empty_cell")
    with TestClient(create_app(reg)) as client:
        assert client.get("/api/health").is_success
        assert not (tmp_path / "data").exists()  # nothing written until it is needed
        assert client.get("/api/cells/c9/thresholds/audit").json() == []
    assert (tmp_path / "data" / "audit.sqlite").is_file()


def test_a_threshold_above_the_physical_ceiling_or_a_loose_confirm_is_refused(
    api: tuple[StandInRegistry, TestClient, AuditLog],
) -> None:
    """1e300 J is refused even when confirmed (the ceiling: MAX_THRESHOLD_J), and ``confirm``
    must be a JSON boolean ("yes" is not true); the scenario model holds the same ceiling."""
    from sara_app.safety.settings import MAX_THRESHOLD_J, ThresholdOverride

    reg, client, _ = api
    for value in (1e300, MAX_THRESHOLD_J * 1.01):
        r = client.put(
            "/api/cells/c1/thresholds", json={**HAND, "energy_J": value, "confirm": True}
        )
        assert r.status_code == 422 and "ceiling" in r.text, r.text
    r = client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": 0.2, "confirm": "yes"})
    assert r.status_code == 422
    r = client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": MAX_THRESHOLD_J,
                                                    "confirm": True})  # fmt: skip
    assert r.status_code == 200, r.text
    with pytest.raises(ValueError):
        ThresholdOverride(region="hand", contact="constrained", shape="blunt", energy_J=1e300)


def test_scenario_edits_neither_read_server_files_nor_raise_limits(
    api: tuple[StandInRegistry, TestClient, AuditLog], tmp_path: Path
) -> None:
    """The hostile-user probe's findings: a threshold-set path loaded a 500 J table, a
    parameter-set path echoed the tokens file, a PATCH of overrides raised the head's limit
    86-fold without confirmation, and a PATCH of another pfl field dropped the engineer's
    tightening. Now: paths 422 (nothing read), raises 409 (only the editor raises), partial
    edits keep the rest of the section."""
    reg, client, _ = api
    loose = json.loads(json.dumps(SEED.model_dump()))
    for region in loose["table"].values():
        for contact in region.values():
            for shape in contact.values():
                shape["energy_J"] = 500.0
    evil = tmp_path / "evil_thresholds.json"
    evil.write_text(json.dumps(loose))
    tokens = tmp_path / "tokens.json"
    tokens.write_text(json.dumps({"tok-9d2b": "operator"}))
    sc = load_scenario("empty_cell").model_dump(mode="json")
    n_sent = len(reg.received)
    for body in (
        {**sc, "shield": {**sc["shield"], "pfl": {"thresholds": str(evil)}}},
        {**sc, "human_params": str(tokens)},
    ):
        r = client.post("/api/cells/c1/scenario", json=body)
        assert r.status_code == 422 and "refers to a file" in r.text, r.text
        assert "tok-9d2b" not in r.text
    r = client.patch("/api/cells/c1/scenario", json={"human_params": str(tokens)})
    assert r.status_code == 422 and "tok-9d2b" not in r.text
    r = client.put("/api/scenarios/mine", json={**sc, "robot": {"name": "/tmp/x.urdf"}})
    assert r.status_code == 422 and "robot.name" in r.text
    head = {"region": "head", "contact": "unconstrained", "shape": "blunt"}
    raise_head = {"shield": {"pfl": {"overrides": [{**head, "energy_J": 9.5}]}}}
    r = client.patch("/api/cells/c1/scenario", json=raise_head)
    assert r.status_code == 409 and "PUT /api/cells/c1/thresholds" in r.text, r.text
    assert len(reg.received) == n_sent  # nothing reached the worker
    # the engineer tightens the head; an unrelated partial pfl edit keeps it
    r = client.put("/api/cells/c1/thresholds", json={**head, "energy_J": 0.05})
    assert r.status_code == 200, r.text
    r = client.patch("/api/cells/c1/scenario", json={"shield": {"pfl": {"min_speed_scale": 0.05}}})
    assert r.status_code == 200, r.text
    pfl = reg.received[-1]["shield"]["pfl"]
    assert pfl["min_speed_scale"] == 0.05 and pfl["overrides"] == [{**head, "energy_J": 0.05}]
    n_sent = len(reg.received)
    r = client.patch("/api/cells/c1/scenario", json={"shield": {"pfl": {"overrides": []}}})
    assert r.status_code == 409 and "head/unconstrained/blunt 0.05 -> " in r.text  # dropped
    r = client.post("/api/cells/c1/scenario", json=sc)  # the file as shipped: head at 0.11 J
    assert r.status_code == 409 and "head/unconstrained/blunt 0.05 -> " in r.text
    assert len(reg.received) == n_sent
    tighter = {"shield": {"pfl": {"overrides": [{**head, "energy_J": 0.04}]}}}
    assert client.patch("/api/cells/c1/scenario", json=tighter).status_code == 200
    # a PATCH onto another scenario file (?base=) is compared with the limits in force too
    r = client.patch("/api/cells/c1/scenario?base=empty_cell", json={"sim": {"seed": 3}})
    assert r.status_code == 409 and "head/unconstrained/blunt 0.04 -> " in r.text, r.text
    r = client.patch("/api/cells/c1/scenario", json={"name": "close_worker"})
    assert r.status_code == 422 and "name" in r.text  # the cell would say it runs another


def test_an_energy_must_be_a_json_number(api: tuple[StandInRegistry, TestClient, AuditLog]) -> None:
    """``true`` was read as 1.0 J and ``"0.1"`` as 0.1 J: a typed value is a number."""
    reg, client, _ = api
    n = len(reg.received)
    for bad in (True, "0.1"):
        r = client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": bad})
        assert r.status_code == 422, r.text
    assert len(reg.received) == n
    assert client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": 0.1}).status_code == 200


def test_a_huge_bad_name_is_not_repeated_in_full(
    api: tuple[StandInRegistry, TestClient, AuditLog],
) -> None:
    """A 900 KB region came back whole in the 422 (the audit row already clipped it)."""
    _, client, _ = api
    body = {**HAND, "region": "x" * 900_000, "energy_J": 1}
    r = client.put("/api/cells/c1/thresholds", json=body)
    assert r.status_code == 422 and len(r.content) < 2_000, len(r.content)
    r = client.get("/api/jobs/" + "j" * 5_000)
    assert r.status_code == 404 and len(r.content) < 2_000, len(r.content)


def test_a_huge_value_in_a_checked_body_is_not_repeated_in_full(
    api: tuple[StandInRegistry, TestClient, AuditLog],
) -> None:
    """FastAPI's own 422 repeated the whole input (a 100 KB retire reason)."""
    _, client, _ = api
    r = client.post("/api/cells/c1/humans/p1/retire", json={"reason": "r" * 100_000})
    assert r.status_code == 422 and len(r.content) < 2_000, len(r.content)
    assert r.json()["detail"][0]["loc"] == ["body", "reason"]
    r = client.put("/api/cells/c1/thresholds", json={**HAND, "energy_J": [0.1] * 50_000})
    assert r.status_code == 422 and len(r.content) < 2_000, len(r.content)
    for body in (b'{"reason": NaN}', b'{"reason": [Infinity, 1]}', b'{"reason": {"a": NaN}}'):
        r = client.post("/api/cells/c1/humans/p1/retire", content=body,
                        headers={"content-type": "application/json"})  # fmt: skip
        assert r.status_code == 422, (body, r.status_code, r.text)
