"""REST routes of the background jobs (:mod:`sara_app.ops.jobs`): what-if runs and evidence reports.

- ``POST /api/cells/{cell}/whatif``: body ``changes`` as for ``PATCH .../scenario`` (applied to
  the scenario the cell runs now); runs both offline, returns the job (202). Nothing is sent to
  the worker: applying the edit is the PATCH with the same body.
- ``POST /api/cells/{cell}/report``: the evidence report of the scenario the cell runs now.
- ``GET /api/jobs``, ``GET /api/jobs/{id}`` (progress; when done the result: the what-if table
  and both runs, or the report's checksum), ``GET /api/jobs/{id}/report`` (the HTML page).

A second job while one runs is refused (409): one at a time beside the live cell.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

from fastapi import Body, FastAPI, HTTPException, Query
from fastapi.responses import HTMLResponse

from sara_app.api.openapi import SCENARIO_CHANGES, body_schema
from sara_app.api.registry import CellRegistry
from sara_app.api.schema import (
    BODY_RESPONSES,
    CHANGE_RESPONSES,
    BaseScenario,
    CellName,
    responses,
)
from sara_app.errors import InputError, UnknownNameError, cut
from sara_app.ops.jobs import MAX_DURATION_S, MAX_EPISODES, JobBusyError, JobRunner
from sara_app.scenario import Scenario
from sara_app.sim.whatif_table import table_markdown

LABEL_VALUE_CHARS = 40
LABEL_CHARS = 200

START_RESPONSES = {
    **CHANGE_RESPONSES,
    **responses(
        404, 409, 422, 500,
        _404="the cell has not been seen on the bus, or the base scenario is unknown",
        _409="another job is running: one at a time",
        _500="the base scenario file is invalid",
    ),
}  # fmt: skip
"""What starting a job may answer besides 202."""


def whatif_label(cell: str, changes: dict[str, Any]) -> str:
    """What a person reads in the job list: ``cell1: what if shield.dt_s = 0.002,
    human_params = "fast"`` (one item per changed value of a section, nested objects as one value;
    long values and labels shortened)."""
    items = []
    for key, value in changes.items():
        if isinstance(value, dict) and value:
            items += [f"{key}.{k} = {_value_text(v)}" for k, v in value.items()]
        else:
            items.append(f"{key} = {_value_text(value)}")
    label = f"{cell}: what if " + ", ".join(items) if items else f"{cell}: what if (no changes)"
    return cut(label, LABEL_CHARS)


def _value_text(value: Any) -> str:
    text = json.dumps(value, allow_nan=True)
    return cut(text, LABEL_VALUE_CHARS)


def add_job_routes(
    app: FastAPI,
    registry: CellRegistry,
    jobs: JobRunner,
    with_changes: Callable[[str, dict[str, Any], str | None], tuple[Scenario, Scenario]],
    check_name: Callable[[str, str], str],
    audit_path: Callable[[], Path | None],
) -> None:
    """``with_changes(cell, changes, base)``: the cell's scenario and the edited one."""

    def start(kind: str, data: dict[str, Any], label: str) -> dict[str, Any]:
        try:
            job = jobs.start(kind, data, label)
        except JobBusyError as e:
            raise HTTPException(409, str(e)) from None
        except InputError as e:  # the query's checks should have said so first
            raise HTTPException(422, str(e)) from None
        return {**job.summary(), "url": f"/api/jobs/{job.id}"}

    @app.post(
        "/api/cells/{cell}/whatif", tags=["jobs"], status_code=202,
        openapi_extra=body_schema(SCENARIO_CHANGES),
        responses={**START_RESPONSES, **BODY_RESPONSES},
    )  # fmt: skip
    def whatif(
        cell: CellName,
        changes: Annotated[dict[str, Any], Body()],
        base: BaseScenario = None,
        duration_s: float | None = Query(None, gt=0.0, le=MAX_DURATION_S),
    ) -> dict[str, Any]:
        """Run the cell's scenario with ``changes`` beside the scenario in force, offline."""
        check_name("cell", cell)
        current, edited = with_changes(cell, changes, base)
        data = {"current": current.model_dump(mode="json"),
                "edited": edited.model_dump(mode="json"), "duration_s": duration_s}  # fmt: skip
        return start("whatif", data, whatif_label(cell, changes))

    @app.post("/api/cells/{cell}/report", tags=["jobs"], status_code=202, responses=START_RESPONSES)
    def report(
        cell: CellName,
        duration_s: float | None = Query(None, gt=0.0, le=MAX_DURATION_S),
        episodes: int = Query(5, ge=0, le=MAX_EPISODES),
    ) -> dict[str, Any]:
        """The evidence report of the scenario the cell runs now (its checksum equals the
        worker's ``config_sha256`` while nothing changes)."""
        check_name("cell", cell)
        current, _ = with_changes(cell, {}, None)
        audit = audit_path()
        settings = {"duration_s": duration_s, "episodes": episodes, "cell": cell,
                    "audit_path": None if audit is None else str(audit),
                    "source": f"the running cell {cell!r}: the scenario it ran when the report "
                              "was requested, live edits included"}  # fmt: skip
        return start("report", {"scenario": current.model_dump(mode="json"),
                                "settings": settings}, f"{cell}: evidence report")  # fmt: skip

    def job_or_404(job_id: str) -> Any:
        try:
            return jobs.get(job_id)
        except UnknownNameError as e:
            raise HTTPException(404, str(e)) from None

    @app.get("/api/jobs", tags=["jobs"])
    def list_jobs() -> list[dict[str, Any]]:
        return jobs.list()

    @app.get("/api/jobs/{job_id}", tags=["jobs"], responses=responses(404))
    def get_job(job_id: str) -> dict[str, Any]:
        """Progress; when done the result (what-if: ``table`` and both runs; report: the
        checksum and ``report_url``)."""
        job = job_or_404(job_id)
        out = job.summary()
        res = job.result()
        if res is not None and job.kind == "whatif":
            out["table"] = table_markdown(res)
            out["result"] = res
        elif res is not None:
            out["checksum"] = res["checksum"]
            out["report_url"] = f"/api/jobs/{job.id}/report"
        return out

    @app.get(
        "/api/jobs/{job_id}/report", tags=["jobs"], response_class=HTMLResponse,
        responses=responses(404, 409, _409="not a report job, or not done yet"),
    )  # fmt: skip
    def get_report(job_id: str) -> HTMLResponse:
        job = job_or_404(job_id)
        if job.kind != "report" or job.state != "done":
            raise HTTPException(409, f"job {job_id} is a {job.kind} job in state {job.state}")
        return HTMLResponse(job.output.read_text())
