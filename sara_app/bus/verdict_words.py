"""A cell's verdict in words, for whoever watches it: a state, a colour and one sentence saying
what the robot does and why (which person and body part, how close; for a fault, which input,
since when and what the operator can do). One place: the API's cell state, the landing page
and the 3D view's banner all show this sentence."""

from __future__ import annotations

from dataclasses import dataclass

from sara_app.bus.messages import VerdictMsg

COLOURS = {
    "moving": "#1b7f3b",
    "slowed": "#b7791f",
    "braking": "#c2410c",
    "fault": "#b91c1c",
    "rest": "#4b5563",
    "offline": "#6b7280",
}
"""The banner's colour per state (green, amber, orange, red, greys)."""

_ADVICE = (
    (("tracker", "skeleton", "stale", "silent", "no skeleton"),
     "check that the tracker runs and sees the cell"),
    (("beyond", "bound", "faster", "violat", "monitor"),
     "a person moved beyond the set in force: the robot resumes once they keep within it"),
    (("robot", "measured state", "tracking_tol", "command"),
     "check the robot's driver and its measured state"),
)  # fmt: skip


@dataclass(frozen=True)
class VerdictWords:
    state: str
    """moving, slowed, braking, fault, rest or offline (keys of :data:`COLOURS`)."""
    colour: str
    sentence: str


def part_words(blocking: list[str]) -> str:
    """``["p1 r_hand", "p1 l_hand", "p2 head"]`` -> ``p1's right hand (and 2 more)``."""
    if not blocking:
        return "a person"
    who, _, part = blocking[0].partition(" ")
    side = {"l": "left ", "r": "right "}.get(part[:1], "") if part[1:2] == "_" else ""
    name = part[2:] if side else part
    more = f" (and {len(blocking) - 1} more)" if len(blocking) > 1 else ""
    return f"{who}'s {side}{name.replace('_', ' ')}{more}"


def _who(v: VerdictMsg) -> str:
    """The body parts not cleared; else the one person in view; else 'a person'."""
    if v.blocking or len(v.skeleton_age_s) != 1:
        return part_words(v.blocking)
    return f"{next(iter(v.skeleton_age_s))} nearby"


def _distance(v: VerdictMsg) -> str:
    """The measured body's surface distance to the robot's link capsules (negative: they
    overlap: the capsules are larger than the links, so this is a touch at most)."""
    d = v.min_distance_m
    if d is None:
        return ""
    return (
        f", {d:.2f} m from the robot"
        if d >= 0
        else f", touching the robot's capsules ({-d:.2f} m deep)"
    )


def _advice(fault: str) -> str:
    low = fault.lower()
    for words, advice in _ADVICE:
        if any(w in low for w in words):
            return advice
    return "the robot resumes on fresh, valid input"


def verdict_state(v: VerdictMsg) -> str:
    """The state of a fresh verdict (a key of :data:`COLOURS` but ``offline``), without the
    sentence: cheap enough for every verdict."""
    if v.faults or v.mode == "fault":
        return "fault"
    if v.mode == "failsafe":
        return "braking"
    if v.mode == "rest":
        return "rest"
    scale = v.speed_scale
    return "slowed" if v.intervened or (scale is not None and scale < 0.999) else "moving"


def verdict_words(
    v: VerdictMsg | None, online: bool = True, fault_for_s: float | None = None
) -> VerdictWords:
    """The words for the newest verdict ``v`` of a cell (None: none yet); ``online``: whether
    it is fresh; ``fault_for_s``: how long the cell has reported a fault."""
    if v is None or not online:
        return _w("offline", "No recent verdict from the cell: this view cannot say the robot "
                  "is verified (its controller brakes on its own without commands)")  # fmt: skip
    state = verdict_state(v)
    if state == "fault":
        what = v.faults[0] if v.faults else "the cell reported a fault"
        since = "" if fault_for_s is None else f" for {fault_for_s:.0f} s"
        return _w("fault", f"Fault{since}: {what}. The robot holds its verified stop; "
                  f"{_advice(what)}")  # fmt: skip
    mode = v.safety_mode.upper()
    if state == "braking":
        return _w("braking", f"Braking along the verified stop ({mode}): "
                  f"{_who(v)}{_distance(v)}")  # fmt: skip
    if state == "rest":
        return _w("rest", "At rest")
    if state == "slowed":
        scale = v.speed_scale
        how = "" if scale is None else f" to {100 * scale:.0f} % of its speed"
        return _w("slowed", f"Moving, slowed{how} by {mode}: {_who(v)}"
                  f"{_distance(v)}")  # fmt: skip
    return _w("moving", f"Moving on its verified path ({mode}){_distance(v)}")


def _w(state: str, sentence: str) -> VerdictWords:
    return VerdictWords(state, COLOURS[state], sentence)
