"""The worker's record of the requests it answered (``sara_app.runtime.ledger``): rows reach
the real SQLite audit log in order with the checksum in force when each was answered; a flood
beyond the queue is counted and reported on the next row written, never silently dropped; a
database that cannot be written costs the caller nothing and is counted."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from waiting import wait_until

from sara_app.errors import ParameterError
from sara_app.ops.audit import AuditLog, WorkerAnswer
from sara_app.runtime import ledger as ledger_mod
from sara_app.runtime.ledger import MAX_QUEUED, AnswerLedger


def test_answers_reach_the_audit_log_in_order_with_the_checksum_in_force(tmp_path: Path) -> None:
    path = tmp_path / "audit.sqlite"
    checksum = ["a" * 64]
    led = AnswerLedger(path, "c1", lambda: checksum[0])
    led.note("edit", "r1", "alice", False, "loosens: the bench removed")
    checksum[0] = "b" * 64
    led.note("edit", "r2", "alice", True, "", confirmed=True)
    led.note("replan", "r3", "", False, "the robot is not at rest")
    rows = wait_until(lambda: len(r := AuditLog(path).worker_answers("c1")) == 3 and r)
    assert [(r["request"], r["request_id"], r["user"], r["outcome"], r["confirmed"],
             r["checksum"][0]) for r in rows] == [
        ("replan", "r3", "unknown", "refused", False, "b"),
        ("edit", "r2", "alice", "applied", True, "b"),
        ("edit", "r1", "alice", "refused", False, "a"),
    ]  # fmt: skip
    assert rows[2]["reason"].startswith("loosens") and AuditLog(path).worker_answers("c2") == []
    led.close()
    assert led.written == 3 and led.lost == 0


def test_a_flood_beyond_the_queue_is_counted_and_reported_on_the_next_row(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = tmp_path / "audit.sqlite"
    monkeypatch.setattr(ledger_mod, "FLUSH_S", 60.0)  # nothing written until close
    led = AnswerLedger(path, "c1", lambda: "")
    for k in range(MAX_QUEUED + 25):
        led.note("retire", f"r{k}", "flood", False, "not known")
    assert led.lost == 25
    led.close()
    rows = AuditLog(path).worker_answers("c1", limit=10_000)
    assert len(rows) == MAX_QUEUED and rows[-1]["request_id"] == "r0"
    assert rows[-1]["lost_before"] == 25 and sum(r["lost_before"] for r in rows) == 25


def test_a_database_that_cannot_be_written_costs_the_caller_nothing(tmp_path: Path) -> None:
    if os.geteuid() == 0:
        blocked = tmp_path / "file"  # root writes anywhere: a path under a file instead
        blocked.write_text("")
        path = blocked / "audit.sqlite"
    else:
        folder = tmp_path / "ro"
        folder.mkdir(mode=0o500)
        path = folder / "audit.sqlite"
    led = AnswerLedger(path, "c1", lambda: "")
    led.note("edit", "r1", "bob", True, "")
    wait_until(lambda: led.lost == 1)
    led.note("edit", "r2", "bob", True, "")
    led.close()
    assert led.lost == 2 and led.written == 0


def test_the_log_refuses_an_answer_it_does_not_know(tmp_path: Path) -> None:
    log = AuditLog(tmp_path / "audit.sqlite")
    bad = WorkerAnswer(1.0, "c1", "delete", "r1", "eve", False, "applied", "", "")
    with pytest.raises(ParameterError, match="'delete'"):
        log.record_worker_answers([bad])
    assert log.worker_answers("c1") == []
