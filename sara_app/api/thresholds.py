"""REST routes of the threshold editor (power and force limiting, Thumm et al. 2024 Table I).

- ``GET /api/cells/{cell}/thresholds``: the effective table of the scenario the cell runs (value,
  source value and key, overridden flag, ISO/TS 15066 Annex A reference).
- ``PUT /api/cells/{cell}/thresholds`` (:class:`ThresholdEditBody`): one entry changed, sent to
  the worker as a whole scenario and applied there live. 200 when the worker accepted it; 409
  when the value exceeds its source's value and ``confirm`` is false (the detail holds the
  warning); 422 for an invalid value or name; 502 when the worker refused; 504 when it did not
  answer (it may still apply it: the audit row says ``no_answer``).
- ``GET /api/cells/{cell}/thresholds/audit?limit=``: the cell's audit rows, newest first.

Every PUT outcome is recorded by :func:`sara_app.ops.threshold_edit.apply_edit` (the same
function the dashboard's panel uses), under the request's user
(:func:`~sara_app.api.guard.request_user`: the token's, as in the request log). The scenario
shown and edited is the one the cell's worker runs (:meth:`CellRegistry.applied_scenario`: its
announcement, or what it accepted from this service). Until the worker has announced it (a
worker or ``serve`` that just started) the GET answers ``state: starting`` with no values and a
PUT 409: never the scenario file's values, which a worker restarted with saved edits does not
run. Edits of one cell are serialised.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from fastapi import FastAPI, HTTPException, Query, Request
from pydantic import BaseModel, ConfigDict, Field, StrictBool, StrictFloat

from sara_app.api.guard import request_user
from sara_app.api.registry import EDIT_TIMEOUT_S, CellRegistry
from sara_app.api.schema import BODY_RESPONSES, CellName, responses
from sara_app.errors import SaraError, WorkerRefusedError, WorkerTimeoutError
from sara_app.ops.audit import MAX_LIMIT, AuditLog
from sara_app.ops.threshold_edit import ConfirmationRequired, apply_edit, threshold_view
from sara_app.safety.settings import MAX_THRESHOLD_J
from sara_app.safety.thresholds import CONTACTS, REGIONS, SHAPES
from sara_app.scenario import Scenario, parse_scenario


class ThresholdEditBody(BaseModel):
    """One threshold entry to change (names are checked by the service, which records every
    request in the audit log, valid or not)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={"examples": [{"region": "hand", "contact": "constrained",
                                         "shape": "blunt", "energy_J": 0.1}]},
    )  # fmt: skip

    region: str = Field(json_schema_extra={"enum": list(REGIONS)}, description="Table I region")
    contact: str = Field(json_schema_extra={"enum": list(CONTACTS)})
    shape: str = Field(json_schema_extra={"enum": list(SHAPES)})
    energy_J: StrictFloat = Field(  # a number: true or "0.1" are refused, not read as 1.0 / 0.1
        description=f"admissible energy in J: a finite number > 0 and <= {MAX_THRESHOLD_J:g}",
        json_schema_extra={"exclusiveMinimum": 0, "maximum": MAX_THRESHOLD_J},
    )  # the range is the schema's; the service checks it so that a refusal is audited too
    confirm: StrictBool = Field(
        False, description="required when energy_J exceeds the source value (true or false)"
    )
    user: str = Field(
        "unknown", max_length=200, deprecated=True,
        description="ignored: the audit records the request's user (the token's user, or "
        "'local' without a token)",
    )  # fmt: skip


class ConfirmationDetail(BaseModel):
    """Why an edit needs ``confirm``: the value exceeds its source's (its refusal audited)."""

    message: str
    needs_confirmation: bool
    region: str
    contact: str
    shape: str
    requested_energy_J: float
    source_energy_J: float
    source_key: str
    source_text: str
    audit_id: int | None


class ThresholdConflict(BaseModel):
    """409: a value above its source's without ``confirm`` (the detail is the warning), or a
    worker that has not announced its scenario yet (the detail is a message)."""

    detail: ConfirmationDetail | str


class ThresholdEditAnswer(BaseModel):
    cell: str
    scenario: str
    accepted: bool
    edit: dict[str, Any]
    audit: dict[str, Any]


AuditSource = AuditLog | Callable[[], AuditLog]


class _Editor:
    def __init__(self, registry: CellRegistry, folder: Path, audit: AuditSource) -> None:
        self.registry, self.folder = registry, folder
        self._audit: AuditLog | None = None
        self._factory: Callable[[], AuditLog] | None = None
        if isinstance(audit, AuditLog):
            self._audit = audit
        else:
            self._factory = audit
        self._lock = threading.Lock()

    def audit(self) -> AuditLog:
        """The audit log (opened on first use when given as a factory)."""
        with self._lock:
            if self._audit is None and self._factory is not None:
                try:
                    self._audit = self._factory()
                except SaraError as e:
                    raise HTTPException(503, f"the audit log is unavailable: {e}") from None
            if self._audit is None:
                raise HTTPException(503, "the audit log is unavailable")
            return self._audit

    def cell_lock(self, cell: str) -> threading.Lock:
        return self.registry.edit_lock(cell)  # shared with the scenario routes

    def base(self, cell: str) -> Scenario | None:
        """The scenario the cell's worker runs, as it announced it (or accepted it from this
        service); None until it has: never the scenario file's, which a restarted worker with
        saved edits does not run."""
        data = self.registry.applied_scenario(cell)
        if data is None:
            return None
        try:
            return parse_scenario(data, f"scenario {cell} runs")
        except SaraError as e:
            raise HTTPException(500, f"the scenario cell {cell!r} runs is invalid: {e}") from None

    def send(self, cell: str, timeout_s: float) -> Callable[[dict[str, Any]], None]:
        def send(data: dict[str, Any]) -> None:
            ans = self.registry.request_params(cell, data, timeout_s)
            if not ans.accepted:
                raise WorkerRefusedError(f"the worker of cell {cell!r} refused: {ans.reason}")

        return send


NOT_ANNOUNCED = (
    "the cell's worker has not announced the scenario it runs yet (it does on starting and "
    "every second): no values until it has"
)


def _confirmation_detail(e: ConfirmationRequired) -> dict[str, Any]:
    p = e.plan
    return {
        "message": str(e),
        "needs_confirmation": True,
        "region": p.region,
        "contact": p.contact,
        "shape": p.shape,
        "requested_energy_J": p.new_energy_J,
        "source_energy_J": p.source_energy_J,
        "source_key": p.source_key,
        "source_text": p.source_text,
        "audit_id": None if e.audit_entry is None else e.audit_entry.id,
    }


def add_threshold_routes(
    app: FastAPI,
    registry: CellRegistry,
    folder: Path,
    audit: AuditSource,
    known_cell: Callable[[str], dict[str, Any]],
    check_name: Callable[[str, str], str],
) -> None:
    """Add the three threshold routes; ``known_cell(cell)`` returns the cell's snapshot or
    raises the HTTP error (422 bad name, 404 never seen); ``check_name(kind, name)`` checks a
    name's form only (422)."""
    ed = _Editor(registry, folder, audit)
    app.state.threshold_audit = ed.audit

    @app.get(
        "/api/cells/{cell}/thresholds",
        tags=["thresholds"],
        responses=responses(404, 422, 500, _500="the scenario the cell runs is invalid"),
    )
    def get_cell_thresholds(cell: CellName) -> dict[str, Any]:
        """The cell's effective contact-energy table: per entry the value in force, its
        source's value and key, whether it is overridden, and the ISO/TS 15066 reference."""
        known_cell(cell)
        sc = ed.base(cell)
        if sc is None:
            return {"cell": cell, "state": "starting", "detail": NOT_ANNOUNCED}
        return {"cell": cell, "state": "running", **threshold_view(sc)}

    @app.put(
        "/api/cells/{cell}/thresholds",
        tags=["thresholds"],
        response_model=ThresholdEditAnswer,
        responses={
            **BODY_RESPONSES,
            **responses(404, 422, 500, 502, 503, 504,
                        _500="the scenario the cell runs is invalid",
                        _502="the worker refused the edited scenario"),
            409: {"model": ThresholdConflict, "description": "above the source value: repeat "
                  "with confirm=true; or the worker has not announced its scenario yet"},
        },
    )  # fmt: skip
    def put_cell_threshold(
        cell: CellName,
        body: ThresholdEditBody,
        request: Request,
        timeout_s: float = Query(EDIT_TIMEOUT_S, gt=0.0, le=120.0),
    ) -> ThresholdEditAnswer:
        """Change one entry of the cell's thresholds live (validated, confirmed when above its
        source value, sent to the worker, recorded in the audit log whatever the outcome)."""
        known_cell(cell)
        log = ed.audit()
        with ed.cell_lock(cell):
            base = ed.base(cell)
            if base is None:
                raise HTTPException(409, f"cell {cell!r}: {NOT_ANNOUNCED}")
            sc = base
            try:
                plan, row = apply_edit(
                    sc,
                    body.region,
                    body.contact,
                    body.shape,
                    body.energy_J,
                    confirm=body.confirm,
                    send=ed.send(cell, timeout_s),
                    audit=log,
                    cell=cell,
                    user=request_user(request),  # one user per request, as the request log
                    via="api",
                    no_answer=(WorkerTimeoutError,),
                )
            except ConfirmationRequired as e:
                raise HTTPException(409, _confirmation_detail(e)) from None
            except WorkerTimeoutError as e:
                raise HTTPException(504, str(e)) from None
            except WorkerRefusedError as e:
                raise HTTPException(502, str(e)) from None
            except SaraError as e:
                raise HTTPException(422, str(e)) from None
        return ThresholdEditAnswer(
            cell=cell, scenario=sc.name, accepted=True, edit=plan.summary(), audit=row.to_dict()
        )

    @app.get(
        "/api/cells/{cell}/thresholds/audit", tags=["thresholds"], responses=responses(422, 503)
    )
    def get_cell_threshold_audit(
        cell: CellName, limit: int = Query(50, ge=1, le=MAX_LIMIT)
    ) -> list[dict[str, Any]]:
        """The cell's threshold changes and refusals, newest first (also for a cell that is
        not on the bus any more)."""
        check_name("cell", cell)
        return [e.to_dict() for e in ed.audit().entries(cell, limit)]
