"""The REST service of a SaRA installation (FastAPI): cells, scenarios, parameter sets.

``create_app(registry, scenarios_folder=None, viewer_url=None, static_dir=None) -> FastAPI``.

- ``GET /api/health``; ``GET /api/links`` (``{"viewer": url, "docs": "/docs"}``);
  ``GET /api/processes``: the processes ``serve`` supervises (pid, running, restarts).
- ``GET /api/cells``, ``GET /api/cells/{cell}``: live status (``CellRegistry`` snapshots);
  ``GET /api/cells/{cell}/events`` and ``GET /api/events``: the same as Server-Sent Events
  (``interval_s``, optional ``limit`` of events).
- ``POST /api/cells/{cell}/scenario``: validate a full scenario, send it to the worker and
  return its answer (422 invalid, 404 unknown cell, 409 refused, 504 no answer);
  ``PATCH`` the same with a partial update (parameters, shield settings, boxes) on a scenario
  file (default: the one the cell runs).
- ``GET /api/scenarios``, ``GET/PUT /api/scenarios/{name}``: list, read, save (validated;
  an existing name is replaced only with ``?overwrite=true``; the stored ``name`` is the URL's;
  :mod:`sara_app.api.library`).
- ``GET/PUT /api/cells/{cell}/thresholds``, ``GET /api/cells/{cell}/thresholds/audit``: the
  threshold editor with its audit log (:mod:`sara_app.api.thresholds`).
- ``POST /api/cells/{cell}/humans/{human_id}/retire``, ``GET /api/cells/{cell}/humans/audit``:
  an operator retires a person no tracker reports any more, audited (:mod:`sara_app.api.people`).
- ``POST /api/cells/{cell}/robot/replan``, ``GET /api/cells/{cell}/robot/audit``: an operator
  confirms where a stopped robot stands so the worker plans from there, audited
  (:mod:`sara_app.api.robot`).
- An edit that loosens what the verdict assumes needs ``?confirm=true`` and is audited,
  ``GET /api/cells/{cell}/assumptions/audit`` lists them (:mod:`sara_app.api.assumptions`);
  ``GET /api/cells/{cell}/worker/audit``: every edit, retirement and re-plan the worker
  answered, whoever sent it (its own record, :mod:`sara_app.runtime.ledger`).
- ``GET /api/params``, ``GET /api/params/{name}``: human-model parameter sets;
  ``GET /api/thresholds``, ``GET /api/thresholds/{name}``: contact-energy threshold sets
  (:mod:`sara_app.api.library`).
- ``/docs``: OpenAPI (:func:`sara_app.api.openapi.add_docs`); ``/``: the landing page from the
  repository's ``static/`` folder.

Names in URLs are ``[A-Za-z0-9_-]{1,64}`` (422 otherwise): no path ever leaves its folder.
"""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Annotated, Any

from fastapi import Body, Depends, FastAPI, HTTPException, Query, Request
from fastapi.responses import StreamingResponse
from fastapi.staticfiles import StaticFiles

import sara_app
from sara_app.api import openapi
from sara_app.api.assumptions import (
    CONFIRM_HOW,
    EditConflict,
    add_assumption_audit_route,
    refusal_detail,
)
from sara_app.api.guard import Guard, request_user
from sara_app.api.jobs import add_job_routes
from sara_app.api.library import (
    add_param_routes,
    add_scenario_routes,
    client_edit,
    example_scenario,
    human_param_sets,
    stored_scenario,
    validate_scenario,
)
from sara_app.api.openapi import EVENT_STREAM, body_schema
from sara_app.api.people import add_people_routes
from sara_app.api.registry import EDIT_TIMEOUT_S, CellRegistry
from sara_app.api.robot import add_robot_routes
from sara_app.api.schema import (
    BODY_RESPONSES,
    GUARD_RESPONSES,
    BaseScenario,
    CellName,
    check_known,
    check_url_name,
    responses,
)
from sara_app.api.thresholds import add_threshold_routes
from sara_app.errors import (
    ParameterError,
    SaraError,
    ScenarioError,
    WorkerRefusedError,
    WorkerTimeoutError,
)
from sara_app.human.params import load_param_set
from sara_app.ops.audit import AuditLog, default_audit_path
from sara_app.ops.client_edits import EditRefusedError, check_no_raise
from sara_app.ops.jobs import JobRunner
from sara_app.ops.loosening import LooseningRefusedError, apply_checked
from sara_app.scenario import (
    Scenario,
    scenario_names,
    scenarios_dir,
)

STATIC_DIR = Path(sara_app.__file__).resolve().parent.parent / "static"


async def _sse(
    request: Request, snapshot: Any, stopping: threading.Event, interval_s: float, limit: int | None
) -> AsyncIterator[str]:
    n = 0
    while limit is None or n < limit:
        if stopping.is_set() or await request.is_disconnected():
            return
        yield f"event: status\ndata: {json.dumps(snapshot())}\n\n"
        n += 1
        if limit is None or n < limit:
            await asyncio.sleep(interval_s)


class EventStream(StreamingResponse):
    """Server-Sent Events (the class tells the OpenAPI document the content type)."""

    media_type = "text/event-stream"


def _stream(request: Request, snapshot: Any, interval_s: float, limit: int | None) -> Any:
    stopping: threading.Event = request.app.state.stopping
    return EventStream(
        _sse(request, snapshot, stopping, interval_s, limit),
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )


def known_cell_check(registry: CellRegistry) -> Callable[[str], dict[str, Any]]:
    """``known_cell(cell)``: the cell's snapshot; HTTP 422 (bad name) or 404 (never seen)."""

    def known_cell(cell: str) -> dict[str, Any]:
        check_url_name("cell", cell)
        snap = registry.cell(cell)
        if snap is None:
            valid = ", ".join(registry.names()) or "(none seen yet)"
            raise HTTPException(404, f"cell {cell!r} has not been seen on the bus; known: {valid}")
        return snap

    return known_cell


CONFIRM_DOC = (
    "apply an edit that loosens what the safety verdict assumes (another human model, a box "
    "removed, a longer timeout, the robot moved, ...): without it such an edit is refused (409, "
    "listing each loosening); either way it is recorded in the audit log"
)

SEND_RESPONSES = {
    **BODY_RESPONSES,
    **responses(
        404, 422, 500, 504,
        _404="the cell has not been seen on the bus, or the base scenario is unknown",
        _422="the scenario is invalid, or refers to a file on the server that the cell does "
        "not already use (clients name shipped items)",
        _500="the base scenario file is invalid",
    ),
    409: {"model": EditConflict, "description": "the edit loosens what the verdict assumes "
          "and confirm is not set (the detail lists the loosenings), or the cell's worker "
          "refused the scenario (the detail gives its reason), or the edit raises a "
          "contact-energy limit in force (only PUT /api/cells/{cell}/thresholds does, "
          "confirmed and audited)"},
}  # fmt: skip
"""What a route that sends a scenario to a cell's worker may answer besides 200."""


def _add_cell_routes(app: FastAPI, registry: CellRegistry, folder: Path) -> None:
    known_cell = known_cell_check(registry)

    @app.get("/api/cells", tags=["cells"])
    def list_cells() -> list[dict[str, Any]]:
        """Every cell seen on the bus, with its live status."""
        return registry.cells()

    @app.get("/api/cells/{cell}", tags=["cells"], responses=responses(404, 422))
    def get_cell(cell: CellName) -> dict[str, Any]:
        return known_cell(cell)

    @app.get(
        "/api/cells/{cell}/events", tags=["cells"], response_model=None,
        response_class=EventStream, responses={**EVENT_STREAM, **responses(422)},
    )  # fmt: skip
    def cell_events(
        request: Request,
        cell: CellName,
        interval_s: float = Query(0.5, ge=0.01, le=10.0),
        limit: int | None = Query(None, ge=1),
    ) -> Any:
        """Server-Sent Events: the cell's snapshot every ``interval_s`` (offline until seen)."""
        check_url_name("cell", cell)

        def snapshot() -> dict[str, Any]:
            return registry.cell(cell) or {"cell": cell, "online": False, "known": False}

        return _stream(request, snapshot, interval_s, limit)

    @app.get(
        "/api/events", tags=["cells"], response_model=None,
        response_class=EventStream, responses={**EVENT_STREAM, **responses(422)},
    )  # fmt: skip
    def all_events(
        request: Request,
        interval_s: float = Query(0.5, ge=0.01, le=10.0),
        limit: int | None = Query(None, ge=1),
    ) -> Any:
        """Server-Sent Events: the list of every cell's snapshot every ``interval_s``."""
        return _stream(request, registry.cells, interval_s, limit)

    def send(cell: str, sc: Scenario, timeout_s: float, confirm: bool, user: str) -> dict[str, Any]:
        """``sc`` to a known cell's worker (``checked_send`` checked the cell), its answer;
        ``confirm``: it carries ``user``'s confirmation of the loosenings found. Raises
        WorkerTimeoutError, WorkerRefusedError or another SaraError (the scenario cannot be
        sent)."""
        ans = registry.request_params(cell, sc.model_dump(mode="json"), timeout_s, confirm, user)
        if not ans.accepted:
            raise WorkerRefusedError(f"the worker of cell {cell!r} refused: {ans.reason}")
        return {"cell": cell, "scenario": sc.name, "accepted": True, "request_id": ans.request_id}

    @app.post(
        "/api/cells/{cell}/scenario", tags=["cells"], openapi_extra=body_schema(openapi.SCENARIO),
        responses=SEND_RESPONSES,
    )  # fmt: skip
    def send_scenario(
        cell: CellName,
        scenario: Annotated[dict[str, Any], Body()],
        request: Request,
        timeout_s: float = Query(EDIT_TIMEOUT_S, gt=0.0, le=120.0),
        confirm: bool = Query(False, description=CONFIRM_DOC),
    ) -> dict[str, Any]:
        """Validate a full scenario and have the cell's worker apply it (all or nothing); an
        edit that loosens what the verdict assumes only with ``confirm``, audited."""
        check_url_name("cell", cell)
        with registry.edit_lock(cell):  # in order with the other edits of this cell
            client_edit(registry.applied_scenario(cell), scenario)
            sc = validate_scenario(scenario, "request body")
            return checked_send(cell, in_force(registry, cell), sc, timeout_s, confirm, request)

    def checked_send(
        cell: str,
        current: Scenario | None,
        sc: Scenario,
        timeout_s: float,
        confirm: bool,
        request: Request,
    ) -> dict[str, Any]:
        """``sc`` sent when it raises no energy limit in force (``current``) and loosens
        nothing, or only with ``confirm`` (recorded)."""
        known_cell(cell)  # an unknown cell is a 404 before anything is compared or recorded
        guarded(cell, current, sc)
        user = request_user(request)
        try:
            answer, found, row = apply_checked(
                current, sc, lambda confirmed: send(cell, sc, timeout_s, confirmed, user),
                confirm=confirm, how_to_confirm=CONFIRM_HOW, audit=app.state.threshold_audit,
                cell=cell, user=user, via="api", no_answer=(WorkerTimeoutError,),
            )  # fmt: skip
        except LooseningRefusedError as e:
            raise HTTPException(409, refusal_detail(e)) from None
        except WorkerTimeoutError as e:
            raise HTTPException(504, str(e)) from None
        except WorkerRefusedError as e:
            raise HTTPException(409, str(e)) from None
        except SaraError as e:
            raise HTTPException(422, str(e)) from None
        return answer if row is None else {**answer, "loosens": found, "audit_id": row["id"]}

    @app.patch(
        "/api/cells/{cell}/scenario", tags=["cells"],
        openapi_extra=body_schema(openapi.SCENARIO_CHANGES), responses=SEND_RESPONSES,
    )  # fmt: skip
    def update_scenario(
        cell: CellName,
        changes: Annotated[dict[str, Any], Body()],
        request: Request,
        base: BaseScenario = None,
        timeout_s: float = Query(EDIT_TIMEOUT_S, gt=0.0, le=120.0),
        confirm: bool = Query(False, description=CONFIRM_DOC),
    ) -> dict[str, Any]:
        """Parameter update: ``changes`` applied to the scenario the cell runs now (as its
        worker announces it, edits from the dashboard included), or to the scenario file
        ``base`` when given (or when the worker has not announced one yet); validated as a whole
        and sent to the worker.

        Objects are merged key by key at every depth, other values (lists too) replaced (so
        an entry of a map, such as ``shield.pfl.link_shapes``, is removed only by sending the
        whole scenario with POST; ``{}`` changes nothing): e.g.
        ``{"shield": {"skeleton_timeout_s": 0.1}}``, ``{"human_params": "cmu_calibrated"}``, or
        ``{"human_params": {"delay_s": 0.05}}`` (the named set's values with that change). An edit
        that loosens what the verdict assumes only with ``confirm``, audited."""
        check_url_name("cell", cell)
        # concurrent PATCHes: one after the other, each on the scenario its predecessor applied
        with registry.edit_lock(cell):
            return _patch(cell, changes, base, timeout_s, confirm, request)

    def _patch(
        cell: str,
        changes: dict[str, Any],
        base: str | None,
        timeout_s: float,
        confirm: bool,
        request: Request,
    ) -> dict[str, Any]:
        if "name" in changes:  # the cell and its threshold table would report another scenario
            raise HTTPException(
                422,
                "name: a scenario's name is its file's; save it under a new name "
                "(PUT /api/scenarios/{name}) and send that, or leave name out",
            )
        _, sc = with_changes(registry, folder, cell, changes, base)
        # the limits and assumptions in force, whatever ``base`` is
        sent = checked_send(cell, in_force(registry, cell), sc, timeout_s, confirm, request)
        return {**sent, "applied": sc.model_dump(mode="json")}


def with_changes(
    registry: CellRegistry, folder: Path, cell: str, changes: dict[str, Any], base: str | None
) -> tuple[Scenario, Scenario]:
    """The scenario ``cell`` runs now (as its worker announces it; else the scenario file
    ``base``, or the one its status names) and that scenario with ``changes`` (see the PATCH
    route), both validated (an invalid result: HTTP 422)."""
    running = None if base else registry.applied_scenario(cell)
    if running is not None:
        data = running
    else:
        base = base or str(known_cell_check(registry)(cell).get("scenario") or "")
        check_known("scenario", base, sorted(set(scenario_names(folder))))
        data = stored_scenario(base, folder)
    current = validate_scenario(data, f"the scenario of cell {cell!r}")
    hp = data["human_params"]
    if isinstance(hp, str) and isinstance(changes.get("human_params"), dict):
        # a partial edit of a named set: start from the set's values, under a new name
        named = load_param_set(hp).model_dump(mode="json")
        data = {**data, "human_params": {**named, "name": f"{hp}_edited"}}
    merged = merge_sections(data, changes)
    client_edit(data, merged)
    return current, validate_scenario(merged, f"{current.name!r} with the changes")


def in_force(registry: CellRegistry, cell: str) -> Scenario | None:
    """The scenario ``cell``'s worker runs, validated (None while it has not announced one)."""
    running = registry.applied_scenario(cell)
    return None if running is None else validate_scenario(running, f"the scenario {cell} runs")


def guarded(cell: str, current: Scenario | None, new: Scenario) -> Scenario:
    """``new`` when it raises no contact-energy limit in force in ``current`` (the scenario the
    cell's worker runs; None while it has not said: the shipped values); HTTP 409 naming the
    threshold editor otherwise (:func:`~sara_app.ops.client_edits.check_no_raise`)."""
    try:
        check_no_raise(current, new, thresholds_path=f"PUT /api/cells/{cell}/thresholds")
    except EditRefusedError as e:
        raise HTTPException(409, str(e)) from None
    return new


def merge_sections(data: dict[str, Any], changes: dict[str, Any]) -> dict[str, Any]:
    """``data`` with ``changes``: objects merged key by key at every depth, other values
    replaced (lists, such as ``humans``, ``environment`` or ``shield.pfl.overrides``, whole).
    Merged one level deep, ``{"shield": {"pfl": {"min_speed_scale": 0.05}}}`` replaced the
    whole ``pfl`` section and dropped the safety engineer's threshold edits with it."""
    out = dict(data)
    for k, v in changes.items():
        old = out.get(k)
        out[k] = merge_sections(old, v) if isinstance(old, dict) and isinstance(v, dict) else v
    return out


def create_app(
    registry: CellRegistry,
    scenarios_folder: Path | str | None = None,
    *,
    viewer_url: str | None = None,
    static_dir: Path | str | None = STATIC_DIR,
    audit: AuditLog | Path | str | None = None,
    processes: Callable[[], dict[str, Any]] | None = None,
    tokens: dict[str, str] | None = None,
    require_token: bool = False,
    hosts: tuple[str, ...] = (),
    jobs: JobRunner | None = None,
    viewers: dict[str, str] | None = None,
) -> FastAPI:
    """The FastAPI app; ``registry`` supplies live cells, ``scenarios_folder`` the scenarios
    (default: the shipped ``scenarios/``), ``viewer_url`` the 3D view's address for the page,
    ``audit`` the threshold audit log (an open log or a path; default
    :func:`~sara_app.ops.audit.default_audit_path`, opened on first use)."""
    if require_token and not tokens:
        raise ParameterError("require_token needs at least one API token")
    folder = Path(scenarios_folder) if scenarios_folder is not None else scenarios_dir()
    if not folder.is_dir():
        raise ScenarioError(f"scenarios folder {str(folder)!r} is not a directory")
    app = FastAPI(
        title="SaRA cell service",
        version=sara_app.__dict__.get("__version__", "0.1.0"),
        description="Live status of SaRA cells, scenarios and human-model parameter sets.",
        docs_url=None,  # served below from installed assets: the default loads them from a CDN
        redoc_url=None,
        responses=GUARD_RESPONSES,
        dependencies=[Depends(openapi.single_query_values)],
    )
    openapi.add_docs(app)
    openapi.install(
        app, lambda: openapi.scenario_schemas(human_param_sets(), example_scenario(folder))
    )
    app.state.registry = registry
    app.state.stopping = threading.Event()  # set by ApiServer.stop(): ends event streams

    @app.get("/api/health", tags=["service"])
    def health() -> dict[str, Any]:
        cells = registry.cells()
        return {
            "ok": True,
            "bus": registry.bus is not None,
            "cells": len(cells),
            "online": sum(c["online"] for c in cells),
        }

    @app.get("/api/processes", tags=["service"])
    def process_status() -> dict[str, Any]:
        """The supervised processes of ``serve`` (pid, running, restarts); empty elsewhere."""
        return {} if processes is None else processes()

    @app.get("/api/links", tags=["service"])
    def links() -> dict[str, Any]:
        out: dict[str, Any] = {"viewer": viewer_url, "docs": "/docs"}
        if viewers:
            out["viewers"] = viewers  # one 3D view per cell (serve --cells N)
        return out

    _add_cell_routes(app, registry, folder)
    audit_log: AuditLog | Callable[[], AuditLog] = (
        audit if isinstance(audit, AuditLog) else (lambda: AuditLog(audit))
    )
    add_threshold_routes(
        app, registry, folder, audit_log, known_cell_check(registry), check_url_name
    )
    add_people_routes(
        app, registry, app.state.threshold_audit, known_cell_check(registry), check_url_name
    )
    add_robot_routes(
        app, registry, app.state.threshold_audit, known_cell_check(registry), check_url_name
    )
    add_assumption_audit_route(app, app.state.threshold_audit, check_url_name)
    runner = jobs if jobs is not None else JobRunner()
    app.state.jobs = runner

    def audit_path() -> Path | None:
        if isinstance(audit, AuditLog):
            return Path(audit.path)
        return Path(audit) if audit is not None else default_audit_path()

    add_job_routes(
        app, registry, runner,
        lambda cell, changes, base: with_changes(registry, folder, cell, changes, base),
        check_url_name, audit_path,
    )  # fmt: skip
    add_scenario_routes(app, folder)
    add_param_routes(app)
    app.add_middleware(
        Guard,
        audit=app.state.threshold_audit,
        tokens=tokens,
        require_token=require_token,
        hosts=hosts,
    )

    @app.get("/api/requests/audit", tags=["service"], responses=responses(422, 503))
    def requests_audit(limit: int = Query(50, ge=1, le=10_000)) -> list[dict[str, Any]]:
        """Every request to a mutating route (refused ones too), newest first."""
        return list(app.state.threshold_audit().requests(limit))

    if static_dir is not None and Path(static_dir).is_dir():
        app.mount("/", StaticFiles(directory=str(static_dir), html=True), name="static")
    return app
