"""The dashboard's "Changes" tab on a real viser server (127.0.0.1, no browser): the worker's
record of the requests it answered, read from a real audit log, newest first, what a sender
wrote shown as text (no markup, no broken table), lost rows counted, re-read only when due, and
an audit log that cannot be read said as such."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import viser

from sara_app.bus.session import free_port
from sara_app.dashboard.changes_panel import REFRESH_S, ChangesPanel, changes_markdown
from sara_app.ops.audit import AuditError, AuditLog, WorkerAnswer


@pytest.fixture(scope="module")
def server() -> Iterator[viser.ViserServer]:
    s = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    yield s
    s.stop()


def _answer(t: float, rid: str, user: str, outcome: str, reason: str = "") -> WorkerAnswer:
    return WorkerAnswer(t, "c1", "edit", rid, user, False, outcome, reason, "ab" * 32)


def test_the_tab_shows_what_the_worker_answered_newest_first(
    server: viser.ViserServer, tmp_path: Path
) -> None:
    log = AuditLog(tmp_path / "audit.sqlite")
    panel = ChangesPanel(server.gui, lambda: log, "c1")
    assert "No request answered" in panel.table.content
    log.record_worker_answers([_answer(1.0, "r1", "alice", "applied")])
    log.record_worker_answers(
        [_answer(2.0, "r2", "x|y <b>*bold*</b>", "refused", "loosens:\nthe bench | removed")],
        lost_before=2,
    )
    panel.refresh_if_due(100.0)
    text = panel.table.content
    lines = [ln for ln in text.splitlines() if ln.startswith("| 1970")]
    assert len(lines) == 2 and "refused" in lines[0] and "alice" in lines[1]  # newest first
    assert all(ln.count("|") - ln.count("\\|") == 7 for ln in lines)  # six columns each
    assert "x\\|y &lt;b&gt;\\*bold\\*&lt;/b&gt;" in lines[0]  # the sender's text, as text
    assert "loosens: the bench \\| removed" in lines[0]  # one line
    assert "2 answered requests could not be recorded" in text
    log.record_worker_answers([_answer(3.0, "r3", "bob", "applied")])
    panel.refresh_if_due(100.0 + REFRESH_S / 2)  # not due: not re-read
    assert "bob" not in panel.table.content
    panel.refresh_if_due(100.0 + REFRESH_S)
    assert "bob" in panel.table.content


def test_an_audit_log_that_cannot_be_read_is_said(server: viser.ViserServer) -> None:
    def unavailable() -> AuditLog:
        raise AuditError("audit log '/nowhere/audit.sqlite' cannot be opened: denied")

    panel = ChangesPanel(server.gui, unavailable, "c1")
    assert "audit log unavailable" in panel.table.content and "denied" in panel.table.content


def test_no_rows_say_so() -> None:
    assert "No request answered" in changes_markdown([])
