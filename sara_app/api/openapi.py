"""The parts of ``/openapi.json`` FastAPI cannot derive from the routes' signatures, and the 405
answers that go with them.

- Scenario bodies: the routes read a scenario (or a partial one) as plain JSON and check it
  themselves, so that a refusal names the field in the project's words (``task.waypoints_rad.0:
  ...``); the document still describes them exactly: :data:`SCENARIO` (a whole scenario),
  :data:`SCENARIO_TO_SAVE` (its name is the URL's) and :data:`SCENARIO_CHANGES` (any of its
  sections, an object-valued one partially: merged key by key at every depth), each with an
  example.
  A route names its body with ``openapi_extra=body_schema(...)``; :func:`install` puts the
  schemas in ``components``.
- Event streams: :data:`EVENT_STREAM`, the ``responses=`` of a Server-Sent Events route.
- 405: the landing page's files are mounted at ``/``, so a method a route does not take would be
  answered by the file server ("Allow: GET, HEAD"); :func:`install` answers it with the methods
  the API's routes at that path take instead.
- A query parameter given twice: no parameter of the API is a list, but FastAPI takes the last
  of repeated values of a scalar one; :func:`single_query_values` refuses them (422).
- The document's pages, ``/docs`` and ``/redoc``, from installed files (:func:`add_docs`).
"""

from __future__ import annotations

import copy
import json
import math
from collections.abc import Callable, MutableMapping
from pathlib import Path
from typing import Any

import fastapi_offline
from fastapi import FastAPI, Request
from fastapi.exception_handlers import http_exception_handler
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.docs import (
    get_redoc_html,
    get_swagger_ui_html,
    get_swagger_ui_oauth2_redirect_html,
)
from fastapi.responses import HTMLResponse, JSONResponse, Response
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles
from pydantic.json_schema import models_json_schema
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match

from sara_app.errors import CLIP_CHARS, SaraError, clipped, cut
from sara_app.human.params import RENAMED, ParamSet
from sara_app.scenario import Scenario

REF = "#/components/schemas/{model}"
SCENARIO, SCENARIO_TO_SAVE, SCENARIO_CHANGES = "Scenario", "ScenarioToSave", "ScenarioChanges"
BODY_MARK = "x-sara-body"

CHANGES_EXAMPLE = {"shield": {"skeleton_timeout_s": 0.1}, "human_params": {"delay_s": 0.05}}
"""The PATCH / what-if example: one shield setting and one value of the named parameter set."""

EVENT_STREAM: dict[int | str, dict[str, Any]] = {
    200: {
        "description": "Server-Sent Events: each event is `event: status` with the snapshot as "
        "JSON in `data` (schema: one event)",
        "content": {
            "text/event-stream": {
                "schema": {
                    "type": "object",
                    "required": ["event", "data"],
                    "properties": {
                        "event": {"const": "status"},
                        "data": {"type": "string", "contentMediaType": "application/json"},
                    },
                }
            }
        },
    }
}


def body_schema(name: str) -> dict[str, Any]:
    """``openapi_extra`` of a route whose JSON body is the schema ``name`` (see the module)."""
    return {BODY_MARK: name}


def scenario_schemas(param_sets: list[str], example: dict[str, Any] | None) -> dict[str, Any]:
    """The components of the scenario bodies (and the models they refer to), by name;
    ``example``: a whole scenario, shown in ``/docs``."""
    _, top = models_json_schema(
        [(Scenario, "validation"), (ParamSet, "validation")], ref_template=REF
    )
    defs: dict[str, Any] = top["$defs"]
    sc = defs[SCENARIO]
    sc["properties"]["human_params"] = {
        "anyOf": [
            {"type": "string", "enum": sorted({*param_sets, *RENAMED})},
            {"$ref": REF.format(model="ParamSet")},
        ],
        "default": sc["properties"]["human_params"].get("default"),
        "description": "a shipped parameter set's name, or a whole parameter set",
    }
    if example is not None:
        sc["examples"] = [example]
    defs[SCENARIO_TO_SAVE] = to_save = copy.deepcopy(sc)
    to_save.update(
        title=SCENARIO_TO_SAVE,
        required=[r for r in sc.get("required", []) if r != "name"],
        description="A scenario to save: its name is the URL's (any `name` here is replaced).",
    )
    to_save["properties"]["name"] = {"description": "ignored: the URL's name is stored"}
    defs[SCENARIO_CHANGES] = changes_schema(sc, defs)
    return defs


def changes_schema(sc: dict[str, Any], defs: dict[str, Any]) -> dict[str, Any]:
    """Any of the scenario's fields; an object-valued one may be partial (its keys merged into
    the current section, at every depth: the schema states the top level's objects partial,
    deeper ones as they are, which the merge also takes); lists (``humans``,
    ``environment``) replace whole."""
    props = {k: _partial(v, defs) for k, v in sc["properties"].items()}
    return {
        "title": SCENARIO_CHANGES,
        "type": "object",
        "additionalProperties": False,
        "properties": props,
        "description": "Changes to a cell's scenario: each section given is merged into the "
        "scenario in force (objects key by key at every depth, other values and lists "
        "replaced); the result is "
        "checked as a whole. A partial `human_params` object edits the named set's values.",
        "examples": [CHANGES_EXAMPLE],
    }


def _partial(prop: dict[str, Any], defs: dict[str, Any]) -> dict[str, Any]:
    """``prop`` with any object it refers to made partial (no required keys, no defaults: a
    missing key keeps the current value)."""
    if "anyOf" in prop:
        return {"anyOf": [_partial(p, defs) for p in prop["anyOf"]]}
    target = defs.get(prop.get("$ref", "").rsplit("/", 1)[-1])
    if target is None or target.get("type") != "object" or "properties" not in target:
        return {k: v for k, v in prop.items() if k != "default"}
    out = {k: v for k, v in copy.deepcopy(target).items() if k != "required"}
    out["properties"] = {
        k: {kk: vv for kk, vv in v.items() if kk != "default"} for k, v in out["properties"].items()
    }
    return out


def install(app: FastAPI, schemas: Callable[[], dict[str, Any]]) -> None:
    """Complete ``app``'s OpenAPI document with the ``schemas()`` bodies (built on the first
    request for it) and answer 405 with the API's methods at the path."""
    derived = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            doc = derived()
            _add_bodies(doc, schemas())
            _errors_as_json(doc)
        return app.openapi_schema or {}

    app.openapi = openapi  # type: ignore[method-assign]
    app.add_exception_handler(StarletteHTTPException, _allow_handler)  # type: ignore[arg-type]
    app.add_exception_handler(RequestValidationError, _invalid_handler)  # type: ignore[arg-type]


def _add_bodies(doc: dict[str, Any], schemas: dict[str, Any]) -> None:
    found = doc.setdefault("components", {}).setdefault("schemas", {})
    clash = [k for k in schemas if k in found and found[k] != schemas[k]]
    if clash:  # a route's model of the same name: two meanings under one name
        raise SaraError(f"OpenAPI component names used twice: {', '.join(clash)}")
    found.update(schemas)
    for path in doc.get("paths", {}).values():
        for op in path.values():
            name = op.pop(BODY_MARK, None)
            if name is None:
                continue
            media: dict[str, Any] = {"schema": {"$ref": REF.format(model=name)}}
            if schemas[name].get("examples"):
                media["example"] = schemas[name]["examples"][0]
            op["requestBody"] = {"required": True, "content": {"application/json": media}}


def _errors_as_json(doc: dict[str, Any]) -> None:
    """Every error answer is JSON, also on a route whose success is HTML or an event stream
    (FastAPI files a route's error bodies under its success's content type)."""
    for path in doc.get("paths", {}).values():
        for op in path.values():
            for code, answer in op.get("responses", {}).items():
                content = answer.get("content")
                if code[0] in "45" and content and "application/json" not in content:
                    answer["content"] = {"application/json": next(iter(content.values()))}


def allowed_methods(app: Any, scope: MutableMapping[str, Any]) -> list[str]:
    """The methods the API's routes take at the request's path (empty: none of them matches)."""
    methods: set[str] = set()
    for route in app.router.routes:
        if isinstance(route, APIRoute) and route.matches(scope)[0] != Match.NONE:
            methods |= route.methods or set()
    return sorted(methods)


async def _allow_handler(request: Request, exc: StarletteHTTPException) -> Response:
    """405 with ``Allow`` naming the methods of the API's routes at the path (the file
    server's "GET, HEAD" only where no route matches); other errors as FastAPI answers them."""
    allowed = allowed_methods(request.app, request.scope) if exc.status_code == 405 else []
    if not allowed:
        return await http_exception_handler(request, exc)
    method, path = request.method, request.url.path
    detail = f"method {method} is not allowed on {path[:200]}; allowed: {', '.join(allowed)}"
    return JSONResponse({"detail": detail}, 405, headers={"Allow": ", ".join(allowed)})


def _short(value: Any) -> Any:
    """``value`` as the answer repeats it (JSON): a long string or a large structure clipped,
    bytes (a body that is not JSON) as text."""
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    if isinstance(value, str):
        return cut(value)
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)  # JSON has no NaN or Infinity
    if isinstance(value, (int, float, bool)) or value is None:
        return value
    text = clipped(value)
    if len(text) >= CLIP_CHARS or not isinstance(value, (list, dict)):
        return text
    try:
        json.dumps(value, allow_nan=False)
    except (TypeError, ValueError):
        return text
    return value


def single_query_values(request: Request) -> None:
    """Refuse (422, as any invalid parameter) a request that gives one of its route's query
    parameters more than once: the document says each is one value (none is a list), and
    FastAPI would take the last silently (schemathesis: ``GET /api/requests/audit?limit=&
    limit=<text>&limit=<object>`` answered 200). An app-wide dependency."""
    route = request.scope.get("route")
    dependant = getattr(route, "dependant", None)
    errors = []
    for name in sorted(_query_names(dependant) if dependant is not None else ()):
        values = request.query_params.getlist(name)
        if len(values) > 1:
            errors.append({"type": "repeated", "loc": ("query", name), "input": values,
                           "msg": f"given {len(values)} times; expected once"})  # fmt: skip
    if errors:
        raise RequestValidationError(errors)


def _query_names(dependant: Any) -> set[str]:
    """The query parameters of a route's dependant and of its dependencies."""
    names = {p.alias for p in dependant.query_params}
    for sub in dependant.dependencies:
        names |= _query_names(sub)
    return names


async def _invalid_handler(request: Request, exc: RequestValidationError) -> Response:
    """422 with FastAPI's list of field errors, each value, key and message clipped: FastAPI
    repeats the whole input (a 100 KB ``reason`` came back whole)."""
    errors = [
        {
            "loc": [_short(p) for p in e.get("loc", ())],
            "msg": _short(str(e.get("msg", ""))),
            "type": e.get("type", ""),
            **({"input": _short(e["input"])} if "input" in e else {}),
        }
        for e in exc.errors()[:20]
    ]
    return JSONResponse({"detail": errors}, status_code=422)


DOCS_ASSETS = "/docs-assets"
"""Where the Swagger UI's and ReDoc's files are served from (the ``fastapi-offline``
package's copies)."""


def add_docs(app: FastAPI) -> None:
    """``/docs`` and ``/redoc`` without internet: their scripts, style sheet and icon come from
    the installed ``fastapi-offline`` package, not from a CDN (a cell's network may have no
    way out)."""
    assets = Path(fastapi_offline.__file__).parent / "static"
    app.mount(DOCS_ASSETS, StaticFiles(directory=assets), name="docs")

    @app.get("/docs", include_in_schema=False)
    def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title=f"{app.title} - API",
            swagger_js_url=f"{DOCS_ASSETS}/swagger-ui-bundle.js",
            swagger_css_url=f"{DOCS_ASSETS}/swagger-ui.css",
            swagger_favicon_url=f"{DOCS_ASSETS}/favicon.png",
            oauth2_redirect_url="/docs/oauth2-redirect",
        )

    @app.get("/docs/oauth2-redirect", include_in_schema=False)
    def docs_redirect() -> HTMLResponse:
        return get_swagger_ui_oauth2_redirect_html()

    @app.get("/redoc", include_in_schema=False)
    def redoc() -> HTMLResponse:
        return get_redoc_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title=f"{app.title} - ReDoc",
            redoc_js_url=f"{DOCS_ASSETS}/redoc.standalone.js",
            redoc_favicon_url=f"{DOCS_ASSETS}/favicon.png",
            with_google_fonts=False,
        )
