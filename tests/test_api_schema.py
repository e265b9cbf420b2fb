"""The OpenAPI document tells the truth: schemathesis runs all of its checks (status codes,
content types and bodies of the answers, request schemas both ways, the Allow header of 405
answers, ...) against every operation of the API, in process (ASGI), on a cell whose worker is
a stand-in; any answer the document does not describe fails the test.

Integrators generate clients from ``/openapi.json``: an undocumented status code, content type
or error body, or a body the schema admits but the service refuses, breaks their client."""

from __future__ import annotations

import os
import shutil
import tempfile
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import schemathesis
from api_stand_ins import KNOWN_PERSON, AnsweringRegistry, InertJobs
from hypothesis import HealthCheck, settings
from schemathesis.specs.openapi.checks import positive_data_acceptance

with warnings.catch_warnings():  # starlette prefers httpx2 for its test client; httpx works
    warnings.filterwarnings("ignore", message=".*httpx.*deprecated")
    from fastapi.testclient import TestClient

from sara_app.api import CellRegistry, create_app, openapi
from sara_app.ops.audit import AuditLog
from sara_app.scenario import scenarios_dir

MAX_EXAMPLES = 10
"""Fuzzed requests per operation (besides the examples and the coverage phase's requests): the
whole run stays well under a minute on a two-core machine."""

SCENARIO_BODIES = frozenset(
    {
        "POST /api/cells/{cell}/scenario",
        "PATCH /api/cells/{cell}/scenario",
        "POST /api/cells/{cell}/whatif",
        "PUT /api/scenarios/{name}",
    }
)
"""Operations whose body is a scenario (or changes to one): besides its schema, a scenario is
checked against its robot model (joint count and limits, link names), the shipped files it
names and cross-field rules, which no JSON schema states; such a refusal (422) is allowed."""

MEMORY_DIR = "/dev/shm" if os.path.isdir("/dev/shm") else None
STREAM_READ_S = 0.3
"""How long an event stream is read (it never ends without ``limit``)."""


@pytest.fixture(scope="module")
def cell_app(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """An app with one running cell (``c1``, scenario ``empty_cell``), a private scenario folder
    and audit log (in memory where the machine has ``/dev/shm``: a committed row on disk takes
    20 ms here, and every change request writes one): every generated request goes to it."""
    tmp = tmp_path_factory.mktemp("api_schema")
    folder = tmp / "scenarios"
    shutil.copytree(scenarios_dir(), folder)
    registry = AnsweringRegistry()
    registry.status("c1", "empty_cell")
    with tempfile.TemporaryDirectory(dir=MEMORY_DIR) as fast:
        audit = AuditLog(Path(fast) / "audit.sqlite")
        app = create_app(registry, folder, audit=audit, jobs=InertJobs())
        assert app.openapi() == DOCUMENTED.openapi()  # the document the requests come from
        yield app


def scenario_refusals_are_semantic(ctx: Any, response: Any, case: schemathesis.Case) -> None:
    """A scenario body the schema admits is refused (422) only by the checks the schema cannot
    state, in the service's words: never for a field the schema allows (an extra field)."""
    meta = case.meta
    if response.status_code != 422 or meta is None or not meta.generation.mode.is_positive:
        return
    detail = response.json()["detail"]
    assert isinstance(detail, str), f"a schema-valid body failed the schema check: {detail}"
    assert "Extra inputs are not permitted" not in detail, detail


DOCUMENTED = create_app(CellRegistry(None), jobs=InertJobs())
"""The service as shipped (its scenarios folder, no cell): where the document comes from at
collection (nothing is written; the requests go to ``cell_app``)."""
CONFIG = schemathesis.Config.from_dict(
    {
        "operations": [
            {
                "include-name": sorted(SCENARIO_BODIES),
                "phases": {"coverage": {"generation": {"mode": "positive"}}},
            }
        ]
    }
)
schema = schemathesis.openapi.from_asgi("/openapi.json", DOCUMENTED, config=CONFIG)


@schema.parametrize()
@settings(max_examples=MAX_EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck))
def test_every_answer_is_what_the_openapi_document_says(
    case: schemathesis.Case, cell_app: Any
) -> None:
    semantic = case.operation.label in SCENARIO_BODIES
    case.call_and_validate(
        app=cell_app,
        timeout=STREAM_READ_S,
        excluded_checks=[positive_data_acceptance] if semantic else None,
        additional_checks=[scenario_refusals_are_semantic] if semantic else None,
    )


def _concrete(template: str) -> str:
    """A documented path with ``cell_app``'s cell, person, scenario and job in its slots."""
    path = template.replace("{cell}", "c1").replace("{human_id}", KNOWN_PERSON)
    return path.replace("{name}", "empty_cell").replace("{job_id}", "whatif-1")


def test_a_method_no_route_takes_is_405_naming_the_routes_methods(cell_app: Any) -> None:
    """Every documented path answers a method none of its operations takes with 405 and
    ``Allow`` listing exactly the documented ones (the landing page's file server behind the
    API would say "GET, HEAD"); the coverage phase above only probes some paths."""
    paths = DOCUMENTED.openapi()["paths"]
    with TestClient(cell_app) as client:
        for template, operations in paths.items():
            path = _concrete(template)
            documented = sorted(m.upper() for m in operations)
            for method in sorted({"DELETE", "OPTIONS", "PATCH", "POST", "PUT"} - set(documented)):
                r = client.request(method, path)
                assert r.status_code == 405, (method, path, r.status_code)
                assert r.headers["allow"] == ", ".join(documented), (method, path)
                assert method in r.json()["detail"] and documented[0] in r.json()["detail"]


QUERY_VALUES = {"integer": "5", "number": "1.0", "boolean": "true", "string": "empty_cell"}


def test_a_query_parameter_given_twice_is_refused_naming_it(cell_app: Any) -> None:
    """Every documented query parameter, given twice with valid values: 422 naming it (FastAPI
    took the last value: schemathesis found ``GET /api/requests/audit`` answering 200 to three
    ``limit`` values); once, it is taken."""
    paths = DOCUMENTED.openapi()["paths"]
    checked = 0
    with TestClient(cell_app) as client:
        for template, operations in paths.items():
            path = _concrete(template)
            for method, op in operations.items():
                for p in op.get("parameters", []):
                    if p["in"] != "query":
                        continue
                    schema = p["schema"]
                    kind = schema.get("type") or schema["anyOf"][0]["type"]
                    value = QUERY_VALUES[kind]
                    url = f"{path}?{p['name']}={value}&{p['name']}={value}"
                    if "text/event-stream" in str(op["responses"]) and p["name"] != "limit":
                        url += "&limit=1"  # a stream taken as asked ends (never, without one)
                    r = client.request(method.upper(), url, json={})
                    assert r.status_code == 422, (method, url, r.status_code, r.text)
                    errors = r.json()["detail"]
                    assert {"loc": ["query", p["name"]], "type": "repeated"}.items() <= errors[
                        0
                    ].items(), (method, url, errors)
                    assert "2 times" in errors[0]["msg"], errors
                    checked += 1
        assert checked >= 20  # every one of them (21 when this was written)
        r = client.get("/api/requests/audit?limit=5")
        assert r.status_code == 200, r.text


def test_the_request_bodies_are_typed_with_examples_and_refuse_extra_fields() -> None:
    """The scenario bodies name their schema and carry an example (shown in ``/docs``); every
    object a request body may hold forbids fields it does not list, as the service does."""
    doc = DOCUMENTED.openapi()
    schemas = doc["components"]["schemas"]
    for path, method, name in (
        ("/api/cells/{cell}/scenario", "post", "Scenario"),
        ("/api/cells/{cell}/scenario", "patch", "ScenarioChanges"),
        ("/api/cells/{cell}/whatif", "post", "ScenarioChanges"),
        ("/api/scenarios/{name}", "put", "ScenarioToSave"),
    ):
        media = doc["paths"][path][method]["requestBody"]["content"]["application/json"]
        assert media["schema"] == {"$ref": f"#/components/schemas/{name}"}
        assert media["example"], (method, path)
    assert schemas["ScenarioChanges"]["examples"] == [openapi.CHANGES_EXAMPLE]
    bodies = [
        media["schema"]
        for ops in doc["paths"].values()
        for op in ops.values()
        for media in op.get("requestBody", {}).get("content", {}).values()
    ]
    objects = list(_objects(bodies, schemas))
    assert len(objects) > 20  # the scenario's sections, the threshold edit, the retire body
    for title, node in objects:
        assert node.get("additionalProperties") is False, title


def _objects(nodes: list[Any], schemas: dict[str, Any]) -> Iterator[tuple[str, dict[str, Any]]]:
    """Every schema with ``properties`` reachable from ``nodes`` (references followed once)."""
    seen: set[str] = set()
    todo = list(nodes)
    while todo:
        node = todo.pop()
        if isinstance(node, list):
            todo += node
        elif isinstance(node, dict):
            ref = node.get("$ref", "")
            if ref and ref not in seen:
                seen.add(ref)
                todo.append(schemas[ref.rsplit("/", 1)[1]])
            if "properties" in node:
                yield str(node.get("title", node)), node
            todo += [v for k, v in node.items() if k not in ("examples", "example", "default")]
