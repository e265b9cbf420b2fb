"""The service's libraries: the scenario files (``GET /api/scenarios``, ``GET/PUT
/api/scenarios/{name}``), the human-model parameter sets (``GET /api/params[/{name}]``) and the
contact-energy threshold sets (``GET /api/thresholds[/{name}]``), and the checks a scenario
from a request passes before it is saved or sent to a cell."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Annotated, Any

from fastapi import Body, FastAPI, HTTPException, Query

from sara_app.api import openapi
from sara_app.api.openapi import body_schema
from sara_app.api.schema import (
    BODY_RESPONSES,
    ParamSetName,
    ScenarioName,
    ThresholdSetName,
    check_known,
    check_url_name,
    responses,
)
from sara_app.errors import SaraError
from sara_app.human.params import available_param_sets, load_param_set
from sara_app.ops.client_edits import EditRefusedError, check_client_edit
from sara_app.safety.thresholds import load_thresholds, threshold_set_names
from sara_app.scenario import (
    SHIPPED_SCENARIOS,
    Scenario,
    check_against_robot,
    load_scenario,
    parse_scenario,
    save_scenario,
    scenario_names,
    scenario_path,
)


def validate_scenario(data: dict[str, Any], origin: str) -> Scenario:
    """A scenario checked as a whole (schema, strictly as the OpenAPI document states it, and
    robot); HTTP 422 with the field otherwise."""
    try:
        sc = parse_scenario(data, origin, strict=True)
        check_against_robot(sc)
    except SaraError as e:
        raise HTTPException(422, str(e)) from None
    return sc


def save_atomic(sc: Scenario, path: Path) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}-", suffix=".json", dir=path.parent)
    os.close(fd)
    try:
        save_scenario(sc, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def client_edit(current: dict[str, Any] | None, new: Any) -> None:
    """HTTP 422 for scenario data that refers to a file the cell's scenario ``current`` does not
    use (:func:`~sara_app.ops.client_edits.check_client_edit`), before it is validated."""
    try:
        check_client_edit(current, new)
    except EditRefusedError as e:
        raise HTTPException(422, str(e)) from None


def example_scenario(folder: Path) -> dict[str, Any] | None:
    """The scenario shown as the example body in ``/docs``: ``empty_cell`` where it is."""
    try:
        return load_scenario("empty_cell", folder).model_dump(mode="json")
    except SaraError:
        return None


def stored_scenario(name: str, folder: Path) -> dict[str, Any]:
    """The scenario file ``name`` as JSON data; HTTP 500 when the stored file is invalid (the
    request is not at fault)."""
    try:
        return load_scenario(name, folder).model_dump(mode="json")
    except SaraError as e:
        raise HTTPException(500, f"stored scenario {name!r} is invalid: {e}") from None


def add_scenario_routes(app: FastAPI, folder: Path) -> None:
    def names() -> list[str]:
        return sorted(set(scenario_names(folder)))

    @app.get("/api/scenarios", tags=["scenarios"])
    def list_scenarios() -> list[str]:
        return names()

    @app.get("/api/scenarios/{name}", tags=["scenarios"], responses=responses(404, 422, 500))
    def get_scenario(name: ScenarioName) -> dict[str, Any]:
        """The validated scenario as JSON."""
        check_known("scenario", name, names())
        return stored_scenario(name, folder)

    @app.put(
        "/api/scenarios/{name}", tags=["scenarios"],
        openapi_extra=body_schema(openapi.SCENARIO_TO_SAVE),
        responses={**BODY_RESPONSES, **responses(409, 422, _409="the name exists (or is "
                                                   "stored in another file, or is a shipped "
                                                   "scenario): not replaced")},
    )  # fmt: skip
    def put_scenario(
        name: ScenarioName,
        scenario: Annotated[dict[str, Any], Body()],
        overwrite: bool = Query(False),
    ) -> dict[str, Any]:
        """Validate and save as ``<name>.json``; replacing an existing name needs overwrite, and
        a shipped scenario is never replaced."""
        check_url_name("scenario", name)
        if name in SHIPPED_SCENARIOS:
            raise HTTPException(
                409, f"scenario {name!r} is shipped with the project and is never replaced; "
                "save the edit under a new name",
            )  # fmt: skip
        client_edit(None, scenario)
        sc = validate_scenario({**scenario, "name": name}, "request body")
        exists = name in names()
        if exists and not overwrite:
            raise HTTPException(
                409, f"scenario {name!r} exists; choose a new name or pass ?overwrite=true"
            )
        path = folder / f"{name}.json"
        if exists and scenario_path(name, folder) != path:  # one file per name
            other = scenario_path(name, folder).name
            raise HTTPException(409, f"scenario {name!r} is stored as {other}; not replaced")
        save_atomic(sc, path)
        return {"name": name, "file": path.name, "overwritten": exists}


def human_param_sets() -> list[str]:
    """Shipped files that are human-model parameter sets (the folder also holds thresholds)."""
    out = []
    for name in available_param_sets():
        try:
            load_param_set(name)
        except SaraError:
            continue
        out.append(name)
    return out


def add_param_routes(app: FastAPI) -> None:
    @app.get("/api/params", tags=["params"])
    def list_params() -> list[str]:
        """Names of the shipped human-model parameter sets."""
        return human_param_sets()

    @app.get("/api/params/{name}", tags=["params"], responses=responses(404, 422))
    def get_params(name: ParamSetName) -> dict[str, Any]:
        check_known("parameter set", name, human_param_sets())
        return load_param_set(name).model_dump(mode="json")

    @app.get("/api/thresholds", tags=["params"])
    def list_thresholds() -> list[str]:
        """Names of the shipped contact-energy threshold sets (power and force limiting)."""
        return list(threshold_set_names())

    @app.get("/api/thresholds/{name}", tags=["params"], responses=responses(404, 422, 500))
    def get_thresholds(name: ThresholdSetName) -> dict[str, Any]:
        check_known("threshold set", name, threshold_set_names())
        try:
            return load_thresholds(name).model_dump(mode="json")
        except SaraError as e:
            raise HTTPException(500, str(e)) from None
