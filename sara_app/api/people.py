"""REST routes of the operator's actions on people: retire a person the trackers no longer
report (the contract's ``sara/<cell>/retire``), every request recorded in the audit log.

- ``POST /api/cells/{cell}/humans/{human_id}/retire`` (:class:`RetireBody`): the worker forgets
  the person (until a tracker lists them or a skeleton arrives again); 200 applied, 409 the
  person was not known or is still reported (newest evidence within the trackers' timeout),
  504 no answer (the worker may or may not have applied it), each audited
  under the request's user (:func:`~sara_app.api.guard.request_user`: the token's).
- ``GET /api/cells/{cell}/humans/audit``: the cell's recorded actions, newest first.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Annotated, Any

from fastapi import FastAPI, HTTPException, Query, Request
from pydantic import BaseModel, ConfigDict, Field

from sara_app.api.guard import request_user
from sara_app.api.registry import CellRegistry, ParamsAnswer
from sara_app.api.schema import BODY_RESPONSES, CellName, HumanId, responses
from sara_app.errors import WorkerTimeoutError
from sara_app.ops.audit import AuditLog


class RetireBody(BaseModel):
    """Why the person is retired (recorded with the request's user)."""

    model_config = ConfigDict(
        extra="forbid", strict=True, json_schema_extra={"examples": [{"reason": "tracker "
                                                        "replaced; nobody there"}]}
    )  # fmt: skip

    reason: Annotated[str, Field(min_length=1, max_length=500)]
    user: Annotated[
        str | None,
        Field(
            min_length=1, max_length=64, deprecated=True,
            description="ignored: the audit records the request's user (the token's user, or "
            "'local' without a token)",
        ),
    ] = None  # fmt: skip


def audited_ask(
    cell: str, ask: Callable[[], ParamsAnswer], record: Callable[..., dict[str, Any]]
) -> dict[str, Any]:
    """An operator's request to ``cell``'s worker (``ask``), its outcome recorded (``record``
    takes ``outcome`` and ``detail``) whatever it is: the stored row when applied; HTTP 409
    when the worker refused (its reason), 504 when it did not answer."""
    try:
        ans = ask()
    except WorkerTimeoutError as e:
        record(outcome="no_answer", detail=str(e))
        raise HTTPException(504, str(e)) from None
    if not ans.accepted:
        record(outcome="refused", detail=ans.reason)
        raise HTTPException(409, f"the worker of cell {cell!r} refused: {ans.reason}")
    return record(outcome="applied", detail="")


def add_people_routes(
    app: FastAPI,
    registry: CellRegistry,
    audit: Callable[[], AuditLog],
    known_cell: Callable[[str], dict[str, Any]],
    check_name: Callable[[str, str], str],
) -> None:
    """Add the retire route and its audit listing (``audit()`` gives the open log)."""

    @app.post(
        "/api/cells/{cell}/humans/{human_id}/retire", tags=["people"],
        responses={**BODY_RESPONSES, **responses(
            404, 409, 422, 503, 504,
            _409="the worker does not know the person, or a tracker still reports them")},
    )  # fmt: skip
    def retire(
        cell: CellName, human_id: HumanId, body: RetireBody, request: Request
    ) -> dict[str, Any]:
        """Forget a person whom no tracker reports any more (the robot otherwise keeps
        braking for them); audited whatever the outcome."""
        known_cell(cell)
        check_name("human", human_id)
        user = request_user(request)  # one user per request, as the request log has it
        entry = audited_ask(
            cell,
            lambda: registry.request_retire(cell, human_id, user, body.reason),
            lambda **outcome: audit().record_person_action(
                cell=cell, human_id=human_id, user=user, reason=body.reason, **outcome
            ),
        )
        return {"cell": cell, "human_id": human_id, "retired": True, "audit": entry}

    @app.get("/api/cells/{cell}/humans/audit", tags=["people"], responses=responses(422, 503))
    def people_audit(
        cell: CellName, limit: int = Query(50, ge=1, le=10_000)
    ) -> list[dict[str, Any]]:
        """The cell's operator actions on people, newest first."""
        check_name("cell", cell)
        return audit().person_actions(cell, limit)
