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

from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any

from fastapi import Body, FastAPI, HTTPException, Query
from fastapi.responses import HTMLResponse

from sara_app.api.registry import CellRegistry
from sara_app.errors import UnknownNameError
from sara_app.ops.jobs import JobBusyError, JobRunner
from sara_app.scenario import Scenario
from sara_app.sim.whatif import table_markdown

MAX_DURATION_S = 60.0
MAX_EPISODES = 50


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
        return {**job.summary(), "url": f"/api/jobs/{job.id}"}

    @app.post("/api/cells/{cell}/whatif", tags=["jobs"], status_code=202)
    def whatif(
        cell: str,
        changes: Annotated[dict[str, Any], Body()],
        base: str | None = Query(None, description="scenario file to start from"),
        duration_s: float | None = Query(None, gt=0.0, le=MAX_DURATION_S),
    ) -> dict[str, Any]:
        """Run the cell's scenario with ``changes`` beside the scenario in force, offline."""
        check_name("cell", cell)
        current, edited = with_changes(cell, changes, base)
        data = {"current": current.model_dump(mode="json"),
                "edited": edited.model_dump(mode="json"), "duration_s": duration_s}  # fmt: skip
        return start("whatif", data, f"{cell}: {sorted(changes)}")

    @app.post("/api/cells/{cell}/report", tags=["jobs"], status_code=202)
    def report(
        cell: str,
        duration_s: float | None = Query(None, gt=0.0, le=MAX_DURATION_S),
        episodes: int = Query(5, ge=0, le=MAX_EPISODES),
    ) -> dict[str, Any]:
        """The evidence report of the scenario the cell runs now (its checksum equals the
        worker's ``config_sha256`` while nothing changes)."""
        check_name("cell", cell)
        current, _ = with_changes(cell, {}, None)
        audit = audit_path()
        settings = {"duration_s": duration_s, "episodes": episodes, "cell": cell,
                    "audit_path": None if audit is None else str(audit)}  # fmt: skip
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

    @app.get("/api/jobs/{job_id}", tags=["jobs"])
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

    @app.get("/api/jobs/{job_id}/report", tags=["jobs"], response_class=HTMLResponse)
    def get_report(job_id: str) -> HTMLResponse:
        job = job_or_404(job_id)
        if job.kind != "report" or job.state != "done":
            raise HTTPException(409, f"job {job_id} is a {job.kind} job in state {job.state}")
        return HTMLResponse(job.output.read_text())
