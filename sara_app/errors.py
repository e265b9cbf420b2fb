"""One exception hierarchy for every domain error of the project.

Messages name the bad value, what was expected and, where there is a finite set, the valid choices.
"""

from __future__ import annotations

from collections.abc import Iterable


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
        super().__init__(f"unknown {kind} {name!r}; valid choices: {', '.join(self.valid)}")

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
