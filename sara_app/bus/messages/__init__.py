"""JSON message schemas of a SaRA cell (schema version 1) and their validated models.

Every message is a JSON object with ``schema_version`` (int, ``SCHEMA_VERSION``), ``seq``
(int >= 0, strictly increasing per publisher and key) and ``stamp_s`` (float: the producer's
sensor or computation time, seconds of the shared wall clock ``time.time()``). Numbers must be
finite (no NaN, no Infinity), unknown fields are refused, list lengths must be consistent.
``MODELS_BY_KIND`` maps each key kind of ``sara_app.bus.keys`` to its model.

Decoding (``sara_app.bus.codec``) validates against these models and counts every rejection by
reason; ``encode(msg) -> bytes`` is the inverse. The models live by concern (``skeleton``,
``robot``, ``verdict``, ``occupancy``, ``operations``, over ``base``); this package is their one
namespace for the rest of the project and for integrators.

Skeletons: ``joints`` maps the point names of the declared ``source`` (a source of
``sara_app.human.skeleton.SOURCES``) to ``[x, y, z]`` metres in frame ``world``. Every point the
source's mapping uses is required; a name outside the source's point set is refused.
``SkeletonMsg.to_arrays()`` gives the ``(J, 3)`` arrays in the skeleton kind's joint order.
"""

from __future__ import annotations

from sara_app.bus.messages.base import (
    MAX_JOINTS,
    SCHEMA_VERSION,
    Finite,
    JointVector,
    Mode,
    MsgBase,
    Name,
    NonNeg,
    Pos,
    Vec3,
)
from sara_app.bus.messages.occupancy import (
    CapsulesMsg,
    ContactClass,
    ContactMsg,
    HumanOccupancyMsg,
    JssaMsg,
    LinkEnergyMsg,
    OccupancyMsg,
    Point,
    RobotOccupancyMsg,
)
from sara_app.bus.messages.operations import (
    MAX_FRAME_PEOPLE,
    FiniteTree,
    ParamsAckMsg,
    ParamsMsg,
    PhaseLockMsg,
    RetireMsg,
    ScenarioStateMsg,
    StatusMsg,
    TrackerFrameMsg,
)
from sara_app.bus.messages.robot import (
    COMMAND_VALID_MIN_S,
    COMMAND_VALID_PERIODS,
    MAX_FAILSAFE_SAMPLES,
    BrakingCause,
    ControllerStatusMsg,
    ReplanMsg,
    RobotCommandMsg,
    RobotStateMsg,
    position_on_stop,
)
from sara_app.bus.messages.skeleton import (
    SkeletonMsg,
    source_points,
)
from sara_app.bus.messages.verdict import (
    JointFlagMsg,
    TrackingFlag,
    TrackingNowMsg,
    VerdictMsg,
    ViolationMsg,
)

__all__ = [
    "BrakingCause",
    "COMMAND_VALID_MIN_S",
    "COMMAND_VALID_PERIODS",
    "CapsulesMsg",
    "ContactClass",
    "ContactMsg",
    "ControllerStatusMsg",
    "Finite",
    "FiniteTree",
    "HumanOccupancyMsg",
    "JointFlagMsg",
    "JointVector",
    "JssaMsg",
    "LinkEnergyMsg",
    "MAX_FAILSAFE_SAMPLES",
    "MAX_FRAME_PEOPLE",
    "MAX_JOINTS",
    "MODELS_BY_KIND",
    "Message",
    "Mode",
    "Name",
    "NonNeg",
    "OccupancyMsg",
    "ParamsAckMsg",
    "ParamsMsg",
    "PhaseLockMsg",
    "Point",
    "Pos",
    "ReplanMsg",
    "RetireMsg",
    "RobotCommandMsg",
    "RobotOccupancyMsg",
    "RobotStateMsg",
    "SCHEMA_VERSION",
    "SCHEMA_VERSIONS",
    "ScenarioStateMsg",
    "SkeletonMsg",
    "StatusMsg",
    "TrackerFrameMsg",
    "TrackingFlag",
    "TrackingNowMsg",
    "Vec3",
    "VerdictMsg",
    "ViolationMsg",
    "encode",
    "position_on_stop",
    "source_points",
]

Message = (
    SkeletonMsg
    | RobotStateMsg
    | RobotCommandMsg
    | VerdictMsg
    | OccupancyMsg
    | ParamsMsg
    | ParamsAckMsg
    | StatusMsg
    | ScenarioStateMsg
    | TrackerFrameMsg
    | RetireMsg
    | ControllerStatusMsg
    | ReplanMsg
)

MODELS_BY_KIND: dict[str, type[MsgBase]] = {
    "skeleton": SkeletonMsg,
    "robot_state": RobotStateMsg,
    "robot_command": RobotCommandMsg,
    "verdict": VerdictMsg,
    "occupancy": OccupancyMsg,
    "params": ParamsMsg,
    "params_ack": ParamsAckMsg,
    "status": StatusMsg,
    "scenario": ScenarioStateMsg,
    "tracker_frame": TrackerFrameMsg,
    "retire": RetireMsg,
    "controller_status": ControllerStatusMsg,
    "robot_replan": ReplanMsg,
}


SCHEMA_VERSIONS: dict[str, int] = {
    kind: int(m.model_fields["schema_version"].default) for kind, m in MODELS_BY_KIND.items()
}
"""Each message kind's schema version (the robot command is at 2: validity and failsafe)."""


def encode(msg: MsgBase) -> bytes:
    """The JSON bytes of a validated message."""
    return msg.model_dump_json().encode()
