"""The worker's verdict of a cycle, with the tracking flags and violations it reports."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from sara_app.bus.messages.base import (
    Finite,
    Mode,
    MsgBase,
    Name,
    NonNeg,
)

TrackingFlag = Literal[
    "jump", "bone", "frozen", "missing", "refused", "speed", "acceleration", "rise",
    "displacement", "stated_velocity", "repeated",
]  # fmt: skip
"""The tracking gate's flags (``jump``, ``bone``, ``frozen``; ``refused``: skeletons refused
for a joint distrusted too long) and the conformance monitor's (``speed``, ``acceleration``,
``rise``: the upward speed of a person whose legs are bounded below the pelvis,
``displacement``: a joint farther from where it was than the set's displacement bound,
``stated_velocity``: a tracker's stated velocity the positions contradict)."""


class ViolationMsg(BaseModel):
    """A person's joint beyond the active parameter set's bound (the person is a fault)."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    human_id: Name
    joint: Name
    quantity: Literal["speed", "acceleration", "rise", "displacement", "stated_velocity"]
    value: Finite
    """m/s or m/s^2: the least speed, acceleration or upward speed (``rise``) that explains the
    measured motion; m for ``displacement`` (the distance beyond the noise bound); m/s for
    ``stated_velocity`` (the stated velocity's distance from the positions' estimate, the bound
    the sum of both uncertainties)."""
    bound: Finite
    stamp_s: Finite


class JointFlagMsg(BaseModel):
    """A flag of one joint: ``flag`` (a ``TrackingFlag``) at ``stamp_s`` (for a held joint:
    since when it is held)."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    joint: Name
    flag: TrackingFlag
    stamp_s: Finite


class TrackingNowMsg(BaseModel):
    """A person's tracking as it stands: the joints the gate holds now (their last trusted
    position, grown by the reach since) and the newest flag of the gate or the monitor."""

    model_config = ConfigDict(strict=True, extra="forbid", frozen=True)

    held: list[JointFlagMsg] = Field(default=[], max_length=32)
    last_flag: JointFlagMsg | None = None


class VerdictMsg(MsgBase):
    """The outcome of one control cycle (key ``sara/<cell>/verdict``), schema version 4 (2: the
    monitor's ``rise`` among the tracking flags and violations' quantities; 3: its
    ``displacement``; 4: its ``stated_velocity``).

    ``results``: model name -> True when that model's human set is free of the robot's set.
    ``skeleton_age_s``: human id -> age of the newest accepted skeleton at decision time.
    ``dropped``: reason -> count of rejected or dropped input messages since the worker started.
    """

    schema_version: Literal[4] = 4  # type: ignore[assignment]
    cell: Name
    safety_mode: Literal["ssm", "pfl", "jssa"]
    mode: Mode
    results: dict[str, bool] = {}
    skeleton_age_s: dict[str, Finite] = {}
    min_distance_m: Finite | None = None
    cycle_time_us: NonNeg
    faults: list[str] = []
    dropped: dict[str, Annotated[int, Field(ge=0)]] = {}
    intervened: bool = False
    """The safety layer changed the nominal motion (failsafe, slowed down, jerk filtered)."""
    speed_scale: NonNeg | None = None
    """PFL: the path-speed cap as a fraction of the admissible speed (1: full speed)."""
    tracking: dict[Name, dict[TrackingFlag, Annotated[int, Field(ge=0)]]] = {}
    """human id -> flag -> joint-frames flagged since the person became known (people with
    no flag are left out)."""
    tracking_now: dict[Name, TrackingNowMsg] = Field(default={}, max_length=64)
    """human id -> the person's tracking now (people never flagged are left out)."""
    violations: list[ViolationMsg] = Field(default=[], max_length=64)
    """The newest violations of every person now on the failsafe for breaking the bounds."""
    blocking: list[Annotated[str, Field(max_length=80)]] = Field(default=[], max_length=16)
    """``"<person id> <body part>"``: the body parts the check could not clear this cycle (why
    the robot brakes or slows; SSM: per body part; empty where the mode says nothing per part)."""
