"""The cell's changes as its worker answered them: a "Changes" tab with the latest rows of the
audit log's ``worker_answers`` for the cell (:mod:`sara_app.runtime.ledger`), whoever sent
them (this dashboard, the API, another program on the bus), re-read every ``REFRESH_S``.

``ChangesPanel(gui, audit_of, cell)`` adds its markdown where the caller opened a tab;
:meth:`ChangesPanel.refresh_if_due` is called from the view's poll. Read-only: nothing here
changes the cell.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import viser

from sara_app.dashboard.tracking_text import md_cell
from sara_app.errors import SaraError
from sara_app.ops.audit import AuditLog

ROWS = 12
"""Rows shown (newest first)."""
REFRESH_S = 2.0
"""How often the rows are re-read (one small query of the audit log)."""
REASON_CHARS = 160
INTRO = (
    "Every scenario edit, retirement and re-plan the cell's worker answered, whoever sent it, "
    "as the worker recorded it (newest first). The user is the one the request names; the "
    "checksum is the configuration in force after it. All rows: "
    "`GET /api/cells/{cell}/worker/audit`; the evidence report lists them too."
)


def _cell_text(x: object, limit: int = 64) -> str:
    """``x`` for a markdown table cell: one line of at most ``limit`` characters, no markdown
    of its own (a user name or reason is whatever the sender wrote), then no HTML and no
    column break (:func:`~sara_app.dashboard.tracking_text.md_cell`)."""
    text = " ".join(str(x).split())[:limit]
    for ch in "\\*_`[]#":
        text = text.replace(ch, "\\" + ch)
    return md_cell(text)


def changes_markdown(rows: Sequence[dict[str, Any]]) -> str:
    """The rows of :meth:`AuditLog.worker_answers` as a markdown table."""
    if not rows:
        return "*No request answered by this cell's worker is recorded yet.*"
    lines = [
        "| time (UTC) | request | user | outcome | reason | checksum |",
        "|---|---|---|---|---|---|",
    ]
    lost = sum(int(r["lost_before"]) for r in rows)
    for r in rows:
        outcome = r["outcome"] if r["outcome"] == "applied" else f"**{r['outcome']}**"
        confirmed = " (confirmed)" if r["confirmed"] else ""
        lines.append(
            f"| {str(r['time_utc'])[:19].replace('T', ' ')} | {_cell_text(r['request'])} | "
            f"{_cell_text(r['user'])} | {outcome}{confirmed} | "
            f"{_cell_text(r['reason'], REASON_CHARS)} | `{_cell_text(r['checksum'], 12)}` |"
        )
    if lost:
        lines.append(f"\n**⚠ {lost} answered requests could not be recorded** (worker's log).")
    return "\n".join(lines)


class ChangesPanel:
    """The "Changes" markdown; see the module notes. ``audit_of()``: the audit log (opened on
    first use; raises when it cannot be)."""

    def __init__(self, gui: viser.GuiApi, audit_of: Callable[[], AuditLog], cell: str) -> None:
        self.audit_of, self.cell = audit_of, cell
        self.intro = gui.add_markdown(INTRO)
        self.table = gui.add_markdown("")
        self._next_s = -math.inf
        self.refresh()

    def refresh(self) -> None:
        """Re-read the rows now."""
        try:
            rows = self.audit_of().worker_answers(self.cell, ROWS)
        except SaraError as e:
            self.table.content = f"**⚠ audit log unavailable:** {_cell_text(e, 300)}"
            return
        self.table.content = changes_markdown(rows)

    def refresh_if_due(self, now_s: float) -> None:
        """:meth:`refresh` when ``REFRESH_S`` passed since the last one (``now_s``: monotonic)."""
        if now_s >= self._next_s:
            self._next_s = now_s + REFRESH_S
            self.refresh()
