"""What the REST service promises in its OpenAPI document, in one place: the error bodies, the
status codes each route may answer and the names in URLs.

Integrators generate clients from ``/openapi.json``, so it must list every status code, content
type and body the service returns (``tests/test_api_schema.py`` holds the service to it):

- :class:`ErrorBody`: every refusal of the service (``{"detail": "<message>"}``; the message
  names the bad value, what was expected and the valid choices).
- :class:`InvalidBody`: 422, either a domain check's message (a string) or the list of field
  errors of the request's schema check (:class:`FieldError`).
- :func:`responses`: the ``responses=`` of a route from the status codes it may answer.
- :data:`GUARD_RESPONSES`: what the front door (:mod:`sara_app.api.guard`) may answer on any
  route; :data:`CHANGE_RESPONSES` and :data:`BODY_RESPONSES`: on a route that changes something
  (with a body).
- :data:`CellName` and the other URL names: ``[A-Za-z0-9_-]{1,64}``, checked by the schema;
  :func:`check_url_name` and :func:`check_known` where a route checks a name itself.
"""

from __future__ import annotations

import re
from typing import Annotated, Any

from fastapi import HTTPException, Path, Query
from pydantic import BaseModel, ConfigDict, Field

NAME_PATTERN = r"^[A-Za-z0-9_-]{1,64}$"
"""A name in a URL (cell, scenario, parameter set, person): no path ever leaves its folder."""
NAME_RULE = "1-64 of [A-Za-z0-9_-]"
NAME_RE = re.compile(NAME_PATTERN)


class ErrorBody(BaseModel):
    """A refusal: what was wrong, what was expected and, where there is a set, the choices."""

    detail: str = Field(examples=["cell 'nope' has not been seen on the bus; known: cell1"])


class FieldError(BaseModel):
    """One field that failed the request's schema check (FastAPI's validation error)."""

    model_config = ConfigDict(extra="allow")

    loc: list[str | int] = Field(description="where: 'path', 'query' or 'body', then the field")
    msg: str
    type: str


class InvalidBody(BaseModel):
    """422: a request that is well formed JSON but not a valid request: the list of field errors
    of the schema check, or the message of the service's own check (a scenario checked against
    its robot, an unknown name, a value out of range), naming the field."""

    detail: str | list[FieldError]


DESCRIPTIONS = {
    400: "the body cannot be read (not UTF-8 JSON)",
    401: "a change without a valid 'Authorization: Bearer <token>' (tokens required)",
    404: "not found: the answer lists the valid names",
    409: "refused in the current state (the detail says why)",
    413: "request body over 1 MiB",
    421: "the Host header is not a name this service answers to (127.0.0.1, localhost)",
    422: "invalid request: the schema's field errors, or the service's check naming the field",
    500: "a stored file (scenario, threshold set) is invalid",
    502: "the cell's worker refused the request",
    503: "the audit log cannot be opened",
    504: "the cell's worker did not answer in time (it may still apply the change)",
}


def responses(*codes: int, **described: str) -> dict[int | str, dict[str, Any]]:
    """``responses=`` for a route that may answer ``codes`` (besides its success), each with
    :class:`ErrorBody` (422: :class:`InvalidBody`); ``described`` overrides a description by
    code (``_409="..."``)."""
    out: dict[int | str, dict[str, Any]] = {}
    for code in codes:
        text = described.get(f"_{code}", DESCRIPTIONS[code])
        out[code] = {"model": InvalidBody if code == 422 else ErrorBody, "description": text}
    return out


GUARD_RESPONSES = responses(413, 421)
"""Any route: the front door refuses a foreign Host (421) and a body over the limit (413)."""
CHANGE_RESPONSES = responses(401)
"""A route that changes something: without a token where tokens are required (401)."""
BODY_RESPONSES = {**CHANGE_RESPONSES, **responses(400)}
"""A route that changes something with a JSON body: also a body that cannot be read (400)."""


def _name(kind: str, example: str) -> Any:
    return Path(pattern=NAME_PATTERN, description=f"{kind}: {NAME_RULE}", examples=[example])


CellName = Annotated[str, _name("a cell's name", "cell1")]
ScenarioName = Annotated[str, _name("a scenario's name", "empty_cell")]
ParamSetName = Annotated[str, _name("a human-model parameter set", "schepp2022_table1")]
ThresholdSetName = Annotated[str, _name("a contact-energy threshold set", "thresholds_thumm2024")]
HumanId = Annotated[str, _name("a person's id", "h1")]
BaseScenario = Annotated[
    str | None,
    Query(
        pattern=NAME_PATTERN,
        description="the scenario file to start from (default: the scenario the cell runs)",
    ),
]


def check_url_name(kind: str, name: str) -> str:
    """``name`` when it is a valid name; HTTP 422 naming the rule otherwise."""
    if not NAME_RE.fullmatch(name):
        raise HTTPException(422, f"{kind} name {name[:80]!r} is invalid; use {NAME_RULE}")
    return name


def check_known(kind: str, name: str, valid: list[str] | tuple[str, ...]) -> str:
    """``name`` when valid and one of ``valid``; HTTP 422 or 404 (listing ``valid``)."""
    check_url_name(kind, name)
    if name not in valid:
        raise HTTPException(404, f"{kind} {name!r} not found; valid: {', '.join(valid)}")
    return name
