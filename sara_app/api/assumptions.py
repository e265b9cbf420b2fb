"""The API's guard on scenario edits that loosen what the verdict assumes
(:mod:`sara_app.ops.loosening`), and their audit listing.

- ``POST`` / ``PATCH /api/cells/{cell}/scenario`` without ``?confirm=true``: an edit that loosens
  anything is refused (409, the detail lists each loosening and the audit row), recorded as
  ``refused``; with it, sent to the worker and recorded with its outcome (``applied``,
  ``refused`` by the worker, ``no_answer``) under the request's user.
- ``GET /api/cells/{cell}/assumptions/audit``: the cell's loosening edits, newest first.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import FastAPI, HTTPException, Query, Request
from pydantic import BaseModel

from sara_app.api.guard import request_user
from sara_app.api.schema import CellName, responses
from sara_app.ops.audit import MAX_LIMIT, AuditLog
from sara_app.ops.loosening import LooseningRefusedError, check_loosening
from sara_app.scenario import Scenario

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


class LooseningGuard:
    """Checks one request's edit and records it (``audit()`` gives the open log)."""

    def __init__(self, audit: Callable[[], AuditLog]) -> None:
        self.audit = audit

    def check(
        self, cell: str, current: Scenario | None, new: Scenario, confirm: bool, request: Request
    ) -> list[str]:
        """The loosenings of ``new`` against ``current`` (the scenario in force); HTTP 409 with
        them, recorded, when there are any and ``confirm`` is false."""
        try:
            return check_loosening(current, new, confirm=confirm, how_to_confirm=CONFIRM_HOW)
        except LooseningRefusedError as e:
            row = self.audit().record_assumption_change(
                cell=cell, scenario=new.name, changes=e.changes, confirmed=False,
                outcome="refused", user=request_user(request), via="api", reason=str(e),
            )  # fmt: skip
            detail = {"message": str(e), "needs_confirmation": True, "loosens": e.changes,
                      "audit_id": row["id"]}  # fmt: skip
            raise HTTPException(409, detail) from None

    def send(
        self,
        cell: str,
        new: Scenario,
        changes: list[str],
        request: Request,
        send: Callable[[], dict[str, Any]],
    ) -> dict[str, Any]:
        """``send()`` (the worker's answer, or an HTTPException); a confirmed loosening is
        recorded with its outcome, and the answer names it (``loosens``, ``audit_id``)."""
        if not changes:
            return send()
        common: dict[str, Any] = {
            "cell": cell, "scenario": new.name, "changes": changes, "confirmed": True,
            "user": request_user(request), "via": "api",
        }  # fmt: skip
        log = self.audit()  # before sending: an edit that cannot be recorded is not made
        try:
            answer = send()
        except HTTPException as e:
            outcome = "no_answer" if e.status_code == 504 else "refused"
            log.record_assumption_change(**common, outcome=outcome, reason=str(e.detail))
            raise
        row = log.record_assumption_change(**common, outcome="applied")
        return {**answer, "loosens": changes, "audit_id": row["id"]}


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
