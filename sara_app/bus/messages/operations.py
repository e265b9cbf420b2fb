"""The cell's operation messages: parameter edits and their answers, status, scenario state,
tracker frames and retirements."""

from __future__ import annotations

import math
from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, field_validator

from sara_app.bus.messages.base import (
    MAX_JOINTS,
    Finite,
    MsgBase,
    Name,
    NonNeg,
    contract_error,
)


def _check_finite_tree(value: object, depth: int = 0) -> None:
    if isinstance(value, float) and not math.isfinite(value):
        raise contract_error("finite_number", f"non-finite number {value!r}")
    if depth > 64:
        raise contract_error("too_deep", "nesting deeper than 64")
    if isinstance(value, dict):
        for v in value.values():
            _check_finite_tree(v, depth + 1)
    elif isinstance(value, list):
        for v in value:
            _check_finite_tree(v, depth + 1)


FiniteTree = Annotated[dict[str, Any], AfterValidator(lambda v: (_check_finite_tree(v), v)[1])]
"""A JSON object (a scenario) whose numbers are all finite."""


class ParamsMsg(MsgBase):
    """A full scenario or parameter update for the worker (key ``sara/<cell>/params``).

    ``confirm``: the sender's user confirmed that the edit loosens what the verdict assumes
    (:mod:`sara_app.ops.loosening`); without it the worker refuses such an edit, whoever sends
    it. ``user``: who sent it and confirmed it (the worker's log and its audit record name
    them). Schema version 2 (version 1 had neither; absent: not confirmed)."""

    schema_version: Literal[2] = 2  # type: ignore[assignment]
    request_id: Name
    scenario: FiniteTree
    confirm: bool = False
    user: Annotated[str, Field(max_length=64)] = ""


class ParamsAckMsg(MsgBase):
    """The worker's answer to a ``ParamsMsg`` (key ``sara/<cell>/params/ack``)."""

    request_id: Name
    accepted: bool
    reason: str = ""


class PhaseLockMsg(BaseModel):
    """Where the worker's cycle phase stands against the skeleton stream (the scenario's
    ``inputs.cycle_phase_lock``; ``sara_app.runtime.cadence``): the person whose skeletons it
    follows (``reference``; None before the first), the learned delay from a skeleton's stamp
    to the cycle that takes it (``delay_s``, a high quantile) and, since the worker started,
    the skeletons taken within that delay (``hits``) and a period or more later (``misses``,
    counted while the grid is locked)."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    reference: Name | None = None
    delay_s: Finite
    hits: Annotated[int, Field(ge=0)] = 0
    misses: Annotated[int, Field(ge=0)] = 0


class StatusMsg(MsgBase):
    """Worker heartbeat, about 1 Hz (key ``sara/<cell>/status``), schema version 3 (version 1
    had no ``loop_time_*``, ``overruns`` or ``robot_q_measured``; version 2 no
    ``phase_lock``)."""

    schema_version: Literal[3] = 3  # type: ignore[assignment]
    cell: Name
    state: Literal["starting", "running", "stopping", "fault"]
    scenario: str = ""
    uptime_s: NonNeg = 0.0
    humans: list[str] = []
    cycle_time_p50_us: NonNeg | None = None
    cycle_time_p99_us: NonNeg | None = None
    loop_time_p50_us: NonNeg | None = None
    loop_time_p99_us: NonNeg | None = None
    """The worker's whole step per cycle (the inputs taken, the shield's cycle, the command and
    verdict sent; ``cycle_time`` is the shield's cycle alone), over its recent cycles."""
    overruns: Annotated[int, Field(ge=0)] = 0
    """Control periods the worker's loop missed since it started (a step that ended more than
    a whole period late)."""
    robot_q_measured: Annotated[list[Finite], Field(max_length=MAX_JOINTS)] | None = None
    """The joint positions (rad) the newest robot state reports; None before a controller
    spoke. What an operator confirms in a re-plan (``robot/replan``)."""
    detail: Annotated[str, Field(max_length=300)] = ""
    """What a ``starting`` worker is doing (building the cell: loading the robot model and
    compiling the kernels, with the seconds so far)."""
    config_sha256: Annotated[str, Field(pattern="^([0-9a-f]{64})?$")] = ""
    """The running configuration's checksum (scenario, parameter and threshold sets, code; see
    ``sara_app.cell.checksum``): the one printed in the cell's evidence report. Empty while
    starting."""
    phase_lock: PhaseLockMsg | None = None
    """The cycle phase's lock onto the skeletons; None while ``inputs.cycle_phase_lock`` is
    off."""


class ScenarioStateMsg(MsgBase):
    """The scenario the worker runs now (key ``sara/<cell>/scenario``): published at start,
    after every accepted update and with each status heartbeat, so that every editor (dashboard,
    API) builds its next edit on what the cell really runs. ``revision`` counts accepted
    updates since the worker started."""

    cell: Name
    revision: Annotated[int, Field(ge=0)]
    scenario: FiniteTree


MAX_FRAME_PEOPLE = 256
"""The most person ids one tracker frame may list (a cell tracks far fewer, see the scenario's
``inputs.max_people``; a longer list is refused as ``invalid``)."""


class TrackerFrameMsg(MsgBase):
    """A tracker's heartbeat (key ``sara/<cell>/tracker/<tracker_id>/frame``): at ``stamp_s``
    the tracker saw exactly the people ``people`` (possibly none). The robot moves only while
    every tracker the scenario declares has sent a fresh frame; a person is forgotten only when
    every declared tracker has sent a frame stamped after the person's last skeleton that does
    not list them (or an operator retires them)."""

    people: Annotated[list[Name], Field(max_length=MAX_FRAME_PEOPLE)]

    @field_validator("people")
    @classmethod
    def _unique(cls, v: list[str]) -> list[str]:
        if len(set(v)) != len(v):
            raise contract_error("invalid", "people lists an id twice")
        return v


class RetireMsg(MsgBase):
    """An operator's decision that a person has left (key ``sara/<cell>/retire``): the worker
    forgets ``human_id`` (until a tracker lists it or a skeleton arrives again) and answers on
    ``params/ack`` with ``request_id``. ``user`` and ``reason`` go to the audit log."""

    request_id: Name
    human_id: Name
    user: Annotated[str, Field(min_length=1, max_length=64)]
    reason: Annotated[str, Field(max_length=500)] = ""
