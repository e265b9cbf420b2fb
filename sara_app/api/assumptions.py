"""What the API answers about scenario edits that loosen what the verdict assumes
(:mod:`sara_app.ops.loosening`: checked, recorded and sent by its ``apply_checked``), and their
audit listing.

- ``POST`` / ``PATCH /api/cells/{cell}/scenario`` without ``?confirm=true``: an edit that loosens
  anything is refused (409, the detail lists each loosening and the audit row), recorded as
  ``refused``; with it, sent to the worker and recorded with its outcome (``applied``,
  ``refused`` by the worker, ``no_answer``) under the request's user.
- ``GET /api/cells/{cell}/assumptions/audit``: the cell's loosening edits, newest first.
- ``GET /api/cells/{cell}/worker/audit``: every edit, retirement and re-plan the cell's worker
  answered, whoever sent it (the API, the dashboard or another editor on the bus), newest first
  (:mod:`sara_app.runtime.ledger`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import FastAPI, Query
from pydantic import BaseModel

from sara_app.api.schema import CellName, responses
from sara_app.ops.audit import MAX_LIMIT, AuditLog
from sara_app.ops.loosening import LooseningRefusedError

CONFIRM_HOW = "repeat the request with ?confirm=true"


class LooseningDetail(BaseModel):
    """Why an edit needs ``confirm``: what it loosens, in words (its refusal audited)."""

    message: str
    needs_confirmation: bool
    loosens: list[str]
    audit_id: int


class EditConflict(BaseModel):
    """409 of a scenario edit: it loosens what the verdict assumes without ``confirm`` (the
    detail lists how), or the worker refused it / it raises an energy limit (a message)."""

    detail: LooseningDetail | str


def refusal_detail(e: LooseningRefusedError) -> dict[str, Any]:
    """The 409 detail of an unconfirmed loosening (:class:`LooseningDetail`; its refusal
    recorded by :func:`~sara_app.ops.loosening.apply_checked`)."""
    row = e.audit_row or {}
    return {"message": str(e), "needs_confirmation": True, "loosens": e.changes,
            "audit_id": row.get("id", -1)}  # fmt: skip


def add_assumption_audit_route(
    app: FastAPI, audit: Callable[[], AuditLog], check_name: Callable[[str, str], str]
) -> None:
    @app.get("/api/cells/{cell}/assumptions/audit", tags=["cells"], responses=responses(422, 503))
    def assumption_audit(
        cell: CellName, limit: int = Query(50, ge=1, le=MAX_LIMIT)
    ) -> list[dict[str, Any]]:
        """The cell's scenario edits that loosened (or would have loosened) what the verdict
        assumes, confirmed or refused, newest first."""
        check_name("cell", cell)
        return audit().assumption_changes(cell, limit)

    @app.get("/api/cells/{cell}/worker/audit", tags=["cells"], responses=responses(422, 503))
    def worker_audit(
        cell: CellName, limit: int = Query(50, ge=1, le=MAX_LIMIT)
    ) -> list[dict[str, Any]]:
        """Every scenario edit, retirement and re-plan the cell's worker answered, whoever sent
        it, as the worker recorded it: the request, the user its message names, whether a
        loosening was confirmed, applied or refused and why, the configuration checksum in
        force after it; newest first."""
        check_name("cell", cell)
        return audit().worker_answers(cell, limit)
