"""Zenoh key expressions of a SaRA cell: every key in one place, built and parsed here.

Key scheme version 1 (``KEY_SCHEME``), all under the root ``sara``:

=========================================  ======  ================================================
key                                        dir.    payload (``sara_app.bus.messages``)
=========================================  ======  ================================================
``sara/<cell>/human/<id>/skeleton``        in      ``SkeletonMsg``: one tracked human
``sara/<cell>/robot/state``                in      ``RobotStateMsg``: measured robot (optional)
``sara/<cell>/robot/command``              out     ``RobotCommandMsg``: the shielded set point
``sara/<cell>/verdict``                    out     ``VerdictMsg``: one per control cycle
``sara/<cell>/occupancy``                  out     ``OccupancyMsg``: sets for display, 10-20 Hz
``sara/<cell>/params``                     in      ``ParamsMsg``: a full scenario / parameter update
``sara/<cell>/params/ack``                 out     ``ParamsAckMsg``: the worker accepts or rejects
``sara/<cell>/status``                     out     ``StatusMsg``: worker heartbeat, about 1 Hz
``sara/<cell>/scenario``                   out     ``ScenarioStateMsg``: the scenario it runs
``sara/<cell>/tracker/<id>/frame``         in      ``TrackerFrameMsg``: a tracker's heartbeat
``sara/<cell>/retire``                     in      ``RetireMsg``: an operator retires a person
``sara/<cell>/controller/status``          in      ``ControllerStatusMsg``: command delivery, 1 Hz
``sara/<cell>/robot/replan``               in      ``ReplanMsg``: the robot is where it stands
=========================================  ======  ================================================

"in"/"out" are seen from the cell worker. ``<cell>`` and ``<id>`` are names of 1-64 characters
from ``[A-Za-z0-9_-]`` (no ``/``, no zenoh wildcards ``*``/``$``/``**``), see ``NAME_PATTERN``.

Key scheme 2 added the tracker frame and retire keys (scheme 1 had no tracker heartbeat);
scheme 3 the robot's re-plan key (an operator's action after the robot was stopped or moved
elsewhere while its controller ran).

API: ``skeleton_key(cell, human_id)``, ``robot_state_key(cell)`` ... ``status_key(cell)``, or
``key(kind, cell, human_id=None)``; subscriptions: ``cell_keys(cell)`` (``sara/<cell>/**``),
``skeleton_keys(cell)`` (``sara/<cell>/human/*/skeleton``), ``all_status_keys()``;
``parse_key(key) -> ParsedKey(cell, kind, human_id)`` (raises ``InputError``);
``check_name(what, name)`` validates a cell or human id.
"""

from __future__ import annotations

import functools
import re
from typing import Literal, NamedTuple, get_args

from sara_app.errors import InputError, UnknownNameError

KEY_SCHEME = 3
ROOT = "sara"
NAME_PATTERN = r"[A-Za-z0-9_-]{1,64}"
_NAME_RE = re.compile(NAME_PATTERN)

Kind = Literal[
    "skeleton",
    "robot_state",
    "robot_command",
    "verdict",
    "occupancy",
    "params",
    "params_ack",
    "status",
    "scenario",
    "tracker_frame",
    "retire",
    "controller_status",
    "robot_replan",
]
KINDS: tuple[str, ...] = get_args(Kind)

# kind -> key suffix after ``sara/<cell>/`` (the skeleton's ``{id}`` is filled in).
_SUFFIX: dict[str, str] = {
    "skeleton": "human/{id}/skeleton",
    "robot_state": "robot/state",
    "robot_command": "robot/command",
    "verdict": "verdict",
    "occupancy": "occupancy",
    "params": "params",
    "params_ack": "params/ack",
    "status": "status",
    "scenario": "scenario",
    "tracker_frame": "tracker/{id}/frame",
    "retire": "retire",
    "controller_status": "controller/status",
    "robot_replan": "robot/replan",
}
_BY_SUFFIX: dict[str, str] = {v: k for k, v in _SUFFIX.items() if "{id}" not in v}

Lane = Literal["control", "request", "evidence", "report", "display"]
LANES: tuple[str, ...] = get_args(Lane)
"""The transport lanes, most urgent first (:data:`LANE_OF`)."""
LANE_OF: dict[str, str] = {
    "robot_command": "control",
    "robot_state": "control",
    "params": "request",
    "params_ack": "request",
    "retire": "request",
    "robot_replan": "request",
    "scenario": "request",
    "skeleton": "evidence",
    "tracker_frame": "evidence",
    "verdict": "report",
    "status": "report",
    "controller_status": "report",
    "occupancy": "display",
}
"""The lane each kind travels in: a zenoh priority of its own (``sara_app.bus.session``). Zenoh
queues each priority apart (in every session and on every router link) and drops a message
when its priority's queue stays full for 1 ms; with every key in one priority, a process that
waited for a CPU lost its commands and its edits' answers behind its display messages
(``sara-app bench --lanes``, 4 busy processes on 2 CPUs: 2.4-5.6 % of the commands and 7-16 %
of the answers lost in one priority, at most 0.15 % of either in lanes; docs/performance.md,
"Lanes")."""
BATCHED_KINDS: tuple[str, ...] = ("occupancy",)
"""Kinds published batched (zenoh's batching, not ``express``): the display message, 10-20 Hz
and large, can wait for the batch's time limit; every other kind goes out at once."""
# kinds whose key holds an id: kind -> (first segment, last segment, what the id names)
_WITH_ID: dict[str, tuple[str, str, str]] = {
    "skeleton": ("human", "skeleton", "human id"),
    "tracker_frame": ("tracker", "frame", "tracker id"),
}


class ParsedKey(NamedTuple):
    """A parsed key: its cell, its kind (one of ``KINDS``) and the id in the key (a human id for
    skeletons, a tracker id for tracker frames, else None)."""

    cell: str
    kind: str
    human_id: str | None


def check_name(what: str, name: object) -> str:
    """Return ``name`` if it is a valid cell or human id, else raise InputError naming it."""
    if not isinstance(name, str) or _NAME_RE.fullmatch(name) is None:
        raise InputError(f"{what} {name!r} is not a valid name; expected {NAME_PATTERN}")
    return name


def key_pattern(kind: str) -> str:
    """The key of ``kind`` with placeholders: ``sara/<cell>/human/<id>/skeleton``."""
    if kind not in _SUFFIX:
        raise UnknownNameError("message kind", kind, KINDS)
    return f"{ROOT}/<cell>/" + _SUFFIX[kind].replace("{id}", "<id>")


def key(kind: str, cell: str, human_id: str | None = None) -> str:
    """The key expression of ``kind`` for ``cell``; ``human_id`` is the id the key holds
    (required for skeletons and tracker frames, refused for the others)."""
    if kind not in _SUFFIX:
        raise UnknownNameError("message kind", kind, KINDS)
    check_name("cell", cell)
    suffix = _SUFFIX[kind]
    if kind in _WITH_ID:
        suffix = suffix.format(id=check_name(_WITH_ID[kind][2], human_id))
    elif human_id is not None:
        raise InputError(f"a {kind} key takes no id; got {human_id!r}")
    return f"{ROOT}/{cell}/{suffix}"


def skeleton_key(cell: str, human_id: str) -> str:
    return key("skeleton", cell, human_id)


def robot_state_key(cell: str) -> str:
    return key("robot_state", cell)


def robot_command_key(cell: str) -> str:
    return key("robot_command", cell)


def verdict_key(cell: str) -> str:
    return key("verdict", cell)


def occupancy_key(cell: str) -> str:
    return key("occupancy", cell)


def params_key(cell: str) -> str:
    return key("params", cell)


def params_ack_key(cell: str) -> str:
    return key("params_ack", cell)


def status_key(cell: str) -> str:
    return key("status", cell)


def scenario_key(cell: str) -> str:
    return key("scenario", cell)


def tracker_frame_key(cell: str, tracker_id: str) -> str:
    return key("tracker_frame", cell, tracker_id)


def retire_key(cell: str) -> str:
    return key("retire", cell)


def controller_status_key(cell: str) -> str:
    return key("controller_status", cell)


def robot_replan_key(cell: str) -> str:
    return key("robot_replan", cell)


def tracker_frame_keys(cell: str) -> str:
    """Every tracker's frame key of one cell: ``sara/<cell>/tracker/*/frame``."""
    return f"{ROOT}/{check_name('cell', cell)}/tracker/*/frame"


def cell_keys(cell: str) -> str:
    """Every key of one cell: ``sara/<cell>/**``."""
    return f"{ROOT}/{check_name('cell', cell)}/**"


def skeleton_keys(cell: str) -> str:
    """Every human's skeleton key of one cell: ``sara/<cell>/human/*/skeleton``."""
    return f"{ROOT}/{check_name('cell', cell)}/human/*/skeleton"


def all_status_keys() -> str:
    """The status keys of every cell: ``sara/*/status``."""
    return f"{ROOT}/*/status"


@functools.lru_cache(maxsize=4096)  # every message is parsed; a cell has a few dozen keys
def parse_key(key_expr: str) -> ParsedKey:
    """Parse a concrete key (no wildcards) into ``ParsedKey``; InputError if it is not ours
    (not cached: a refused key is parsed again)."""
    parts = str(key_expr).split("/")
    if len(parts) < 3 or parts[0] != ROOT:
        raise InputError(f"key {key_expr!r} is not a {ROOT}/<cell>/... key")
    cell = check_name("cell", parts[1])
    rest = parts[2:]
    for kind, (first, last, what) in _WITH_ID.items():
        if len(rest) == 3 and rest[0] == first and rest[2] == last:
            return ParsedKey(cell, kind, check_name(what, rest[1]))
    plain = _BY_SUFFIX.get("/".join(rest))
    if plain is None:
        valid = ", ".join(_SUFFIX.values())
        raise InputError(f"key {key_expr!r}: unknown suffix {'/'.join(rest)!r}; valid: {valid}")
    return ParsedKey(cell, plain, None)
