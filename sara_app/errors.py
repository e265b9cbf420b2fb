"""One exception hierarchy for every domain error of the project.

Messages name the bad value, what was expected and, where there is a finite set, the valid choices.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

CLIP_CHARS = 120
"""How much of a bad value a message repeats (a request may send megabytes)."""


def cut(text: str, limit: int = CLIP_CHARS) -> str:
    """``text`` cut to ``limit`` characters with an ellipsis."""
    return text if len(text) <= limit else text[: limit - 3] + "..."


def clipped(value: object, limit: int = CLIP_CHARS) -> str:
    """``repr(value)``, cut to ``limit`` characters with an ellipsis."""
    return cut(repr(value), limit)


def describe_validation(err: Any, *, with_input: bool, limit: int = 5) -> str:
    """A pydantic ``ValidationError`` as one line: each field's location and message (at most
    ``limit``), with the value it got (clipped) only when ``with_input``: a file read on the
    server's side must not come back in an answer (a path to a token file was answered with
    its tokens), nor its unexpected keys (the tokens are keys)."""
    errors = err.errors(include_input=with_input, include_url=False)
    parts = []
    for e in errors[:limit]:
        path, msg = list(e["loc"]), e["msg"]
        if not with_input and e["type"] == "extra_forbidden":  # the key is the file's content
            path, msg = path[:-1], "has a field that is not allowed"
        loc = ".".join(str(p) for p in path) or "<root>"  # a key may be a request's megabyte
        got = f" (got {clipped(e['input'], 80)})" if with_input and "input" in e else ""
        parts.append(f"{cut(loc, CLIP_CHARS)}: {cut(msg, 2 * CLIP_CHARS)}{got}")
    more = len(errors) - limit
    return "; ".join(parts) + (f" (+{more} more)" if more > 0 else "")


class SaraError(Exception):
    """Base of all domain errors."""


class InputError(SaraError, ValueError):
    """A measurement, array or argument is malformed (shape, NaN, order in time)."""


class ParameterError(SaraError, ValueError):
    """A parameter set is incomplete, has unknown names or out-of-range values."""


class UnknownNameError(ParameterError, KeyError):
    """A name (joint, body part, model, source) is not one of the valid choices."""

    def __init__(self, kind: str, name: str, valid: Iterable[str]) -> None:
        self.kind, self.name, self.valid = kind, name, tuple(valid)
        super().__init__(f"unknown {kind} {clipped(name)}; valid choices: {', '.join(self.valid)}")

    def __str__(self) -> str:  # KeyError would quote the whole message otherwise
        return str(self.args[0])


class RecordingError(InputError):
    """A recording file cannot be read into the project's skeleton model."""


class ScenarioError(SaraError, ValueError):
    """A scenario file or edit is invalid."""


class RobotModelError(SaraError, ValueError):
    """A robot description, joint limit or trajectory request is invalid."""


class AccessError(SaraError, PermissionError):
    """A change was asked for without the credential the service requires."""


class WorkerTimeoutError(SaraError):
    """A cell worker did not answer a parameter request (absent, busy or not subscribed): it may
    still apply it later."""


class WorkerRefusedError(SaraError):
    """The cell's worker answered a scenario request with a refusal (its reason in the
    message)."""
