"""The threshold audit log: a real SQLite file with a versioned schema, rows that survive a
reopen, filters (cell, newest first, limit), concurrent writers in several processes."""

from __future__ import annotations

import multiprocessing as mp
import sqlite3
from datetime import datetime
from pathlib import Path

import pytest

from sara_app.errors import ParameterError
from sara_app.ops.audit import (
    ENV_VAR,
    SCHEMA_VERSION,
    AuditError,
    AuditLog,
    default_audit_path,
)


class Clock:
    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        self.t += 1.0
        return self.t


def _row(log: AuditLog, cell: str, new: float, **kw: object) -> None:
    args: dict = {
        "cell": cell,
        "scenario": "demo",
        "entry": ("hand", "constrained", "blunt"),
        "requested": new,
        "outcome": "applied",
        "old_energy_J": 0.12,
        "source_energy_J": 0.12,
        "source_key": "iso15066",
    }
    log.record(**(args | kw))


def test_schema_created_versioned_and_persistent(tmp_path: Path) -> None:
    path = tmp_path / "sub" / "dir" / "audit.sqlite"  # folders are created
    log = AuditLog(path, clock=Clock(1_700_000_000.0))
    assert path.is_file() and log.schema_version == SCHEMA_VERSION
    _row(log, "c1", 0.1, user="  ana  ", exceeds_source=False, confirmed=True, via="dashboard")
    e = log.entries()[0]
    assert e.time_epoch_s == 1_700_000_001.0
    assert datetime.fromisoformat(e.time_utc).timestamp() == e.time_epoch_s
    assert e.time_utc.endswith("+00:00")
    assert (e.cell, e.scenario, e.region, e.contact, e.shape) == (
        "c1",
        "demo",
        "hand",
        "constrained",
        "blunt",
    )
    assert (e.old_energy_J, e.new_energy_J, e.source_energy_J) == (0.12, 0.1, 0.12)
    assert e.user == "ana" and e.confirmed and not e.exceeds_source and e.via == "dashboard"
    again = AuditLog(path)  # reopening keeps the rows and does not recreate anything
    assert again.entries() == [e]
    with sqlite3.connect(path) as con:
        assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        con.execute(f"PRAGMA user_version = {SCHEMA_VERSION + 1}")
    with pytest.raises(AuditError, match=f"schema version {SCHEMA_VERSION + 1}"):
        AuditLog(path)


def test_an_older_file_is_upgraded_keeping_its_rows(tmp_path: Path) -> None:
    """A file of schema 2 (no request table yet) gains the tables added since when opened, and
    keeps what it held."""
    path = tmp_path / "old.sqlite"
    _row(AuditLog(path), "c1", 0.1)
    with sqlite3.connect(path) as con:  # as version 2 left it
        con.execute("DROP TABLE api_requests")
        con.execute("DROP TABLE assumption_changes")
        con.execute("DROP TABLE robot_actions")
        con.execute("PRAGMA user_version = 2")
    log = AuditLog(path)
    assert log.schema_version == SCHEMA_VERSION and len(log.entries()) == 1
    log.record_request("POST", "/api/x", 401, "127.0.0.1", "local", 3)
    assert [r["status"] for r in log.requests()] == [401]
    log.record_assumption_change(cell="c1", scenario="s", changes=["a: 1 -> 2"],
                                 confirmed=True, outcome="applied")  # fmt: skip
    assert [r["changes"] for r in log.assumption_changes("c1")] == [["a: 1 -> 2"]]
    log.record_robot_action(cell="c1", q_rad=[0.1], user="ann", reason="r", outcome="applied")
    assert [r["q_rad"] for r in log.robot_actions("c1")] == [[0.1]]


def test_robot_actions_keep_the_positions_confirmed(tmp_path: Path) -> None:
    log = AuditLog(tmp_path / "a.sqlite")
    first = log.record_robot_action(cell="c1", q_rad=[0.1, -2.5, float("nan")], user="ann",
                                    reason="moved by hand", outcome="refused",
                                    detail="not at rest")  # fmt: skip
    log.record_robot_action(cell="c2", q_rad=[0.0], user="bob", reason="x", outcome="applied")
    second = log.record_robot_action(cell="c1", q_rad=[0.2], user="ann", reason="again",
                                     outcome="no_answer")  # fmt: skip
    rows = log.robot_actions("c1")
    assert [r["id"] for r in rows] == [second["id"], first["id"]]
    assert rows[1] == first and first["q_rad"] == [0.1, -2.5, None]  # never a NaN in JSON
    assert (first["action"], first["user"], first["detail"]) == ("replan", "ann", "not at rest")
    assert [r["outcome"] for r in log.robot_actions("c1", 1)] == ["no_answer"]
    with pytest.raises(ParameterError, match="outcome"):
        log.record_robot_action(cell="c1", q_rad=[], user="a", reason="r", outcome="maybe")
    with pytest.raises(ParameterError, match="limit"):
        log.robot_actions("c1", 0)


def test_loosening_edits_are_recorded_per_cell_newest_first(tmp_path: Path) -> None:
    log = AuditLog(tmp_path / "a.sqlite")
    changes = ["shield.skeleton_timeout_s: 0.2 -> 1.0 (why)", "environment box 'b' removed"]
    first = log.record_assumption_change(cell="c1", scenario="s", changes=changes,
                                         confirmed=False, outcome="refused", user="ann",
                                         via="dashboard", reason="not confirmed")  # fmt: skip
    log.record_assumption_change(cell="c2", scenario="s", changes=["x"], confirmed=True,
                                 outcome="applied")  # fmt: skip
    second = log.record_assumption_change(
        cell="c1", scenario="s", changes=changes, confirmed=True, outcome="no_answer", user="ann"
    )
    rows = log.assumption_changes("c1")
    assert [r["id"] for r in rows] == [second["id"], first["id"]]
    assert rows[1] == {**first, "changes": changes, "confirmed": False, "user": "ann",
                       "via": "dashboard", "outcome": "refused"}  # fmt: skip
    assert [r["outcome"] for r in log.assumption_changes("c1", 1)] == ["no_answer"]
    with pytest.raises(ParameterError, match="outcome"):
        log.record_assumption_change(cell="c1", scenario="s", changes=[], confirmed=True,
                                     outcome="maybe")  # fmt: skip
    with pytest.raises(ParameterError, match="limit"):
        log.assumption_changes("c1", 0)


def test_filters_order_limit_and_validation(tmp_path: Path) -> None:
    log = AuditLog(tmp_path / "a.sqlite", clock=Clock(0.0))
    for i in range(12):
        _row(log, "c1" if i % 3 else "c2", 0.01 * (i + 1))
    _row(log, "c1", float("nan"), outcome="refused", reason="not finite", user="")
    rows = log.entries("c1", limit=100)
    assert len(rows) == 9 and all(r.cell == "c1" for r in rows)
    assert [r.id for r in rows] == sorted((r.id for r in rows), reverse=True)  # newest first
    assert rows[0].new_energy_J is None and rows[0].requested == "nan" and rows[0].user == "unknown"
    assert [r.new_energy_J for r in log.entries("c2")] == pytest.approx([0.1, 0.07, 0.04, 0.01])
    assert len(log.entries(limit=5)) == 5 and len(log.entries()) == 13
    assert log.entries("nobody") == []
    for bad in (0, -1, 10_001, 2.5, True):
        with pytest.raises(ParameterError, match="limit"):
            log.entries(limit=bad)  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="outcome"):
        _row(log, "c1", 0.1, outcome="maybe")
    with pytest.raises(ParameterError, match="at most 200"):
        _row(log, "c1", 0.1, user="x" * 201)
    assert len(log.entries()) == 13  # nothing written by the refused calls


def _writer(path: str, cell: str, n: int) -> None:
    log = AuditLog(path, busy_timeout_s=30.0)
    for i in range(n):
        _row(log, cell, 0.001 * (i + 1))


def test_concurrent_writers_in_several_processes(tmp_path: Path) -> None:
    path = str(tmp_path / "shared.sqlite")
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_writer, args=(path, f"w{k}", 40)) for k in range(4)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(60)
    assert [p.exitcode for p in procs] == [0, 0, 0, 0]
    log = AuditLog(path)
    rows = log.entries(limit=1000)
    assert len(rows) == 160 and len({r.id for r in rows}) == 160
    for k in range(4):
        mine = log.entries(f"w{k}", limit=1000)
        # each writer's rows in its own order: ids increase with its values
        want = [0.001 * i for i in range(40, 0, -1)]
        assert [r.new_energy_J for r in mine] == pytest.approx(want)


def test_default_path_from_environment(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "data"))
    assert default_audit_path() == tmp_path / "data" / "audit.sqlite"
    log = AuditLog()
    assert log.path == tmp_path / "data" / "audit.sqlite" and log.path.is_file()
    monkeypatch.delenv(ENV_VAR)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "xdg"))
    assert default_audit_path() == tmp_path / "xdg" / "sara_app" / "audit.sqlite"


def test_unwritable_location_is_an_audit_error(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.raises(AuditError, match="cannot be created"):
        AuditLog(blocker / "audit.sqlite")


def test_the_file_is_its_owners_only(tmp_path: Path) -> None:
    """Who changed what is not everyone's to read: the file (and its WAL files) 0600, also an
    existing one created readable by all."""
    import os
    import stat

    log = AuditLog(tmp_path / "a.sqlite")
    log.record_request("PUT", "/x", 200, "127.0.0.1", "anna", 3)
    for f in tmp_path.iterdir():
        assert stat.S_IMODE(f.stat().st_mode) == 0o600, f
    os.chmod(tmp_path / "a.sqlite", 0o644)
    AuditLog(tmp_path / "a.sqlite")
    assert stat.S_IMODE((tmp_path / "a.sqlite").stat().st_mode) == 0o600
