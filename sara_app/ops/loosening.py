"""Which changes of a scenario loosen what the cell's verdict assumes.

A scenario edit from a client (the API's ``POST``/``PATCH .../scenario``, the dashboard's
Scenario tab and what-if *Apply*) can weaken the verification without touching a threshold: a
human model with smaller bounds, a box of the environment removed (no clamping against it is
considered any more), a model added to the SSM check (a body part is cleared when ANY model's
set is free, so every model added is one more chance to clear it), a longer skeleton timeout,
the robot's base moved (the cell would verify a robot that is not where it stands). Such an
edit is applied only with an explicit confirmation and is recorded in the audit log with who
confirmed it (:meth:`sara_app.ops.audit.AuditLog.record_assumption_change`), as the threshold
editor does for a limit above its source.

:func:`loosenings` compares the scenario in force with the edited one field by field:

- **free** fields are not safety assumptions (the task, the speed limits of the task, the
  simulated people, the safety mode the operator chooses, the speed scaling's tuning, the
  description); the contact-energy table is the threshold editor's and
  :func:`sara_app.ops.client_edits.check_no_raise` refuses raising it;
- fields with a **direction** loosen only one way (a shorter timeout, a larger link margin, an
  added box or tracker, a model removed are tightenings and pass);
- **every other field** loosens whenever it changes (CONSERVATIVE: a field added to the
  scenario later needs a confirmation until it is given a rule here).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import Any, TypeVar

from sara_app.errors import ParameterError, clipped
from sara_app.ops.audit import AuditLog
from sara_app.safety.topology import ROBOT_UNCLAMPABLE_PAIRS
from sara_app.scenario import Scenario

__all__ = ["LooseningRefusedError", "apply_checked", "check_loosening", "loosenings"]

T = TypeVar("T")

FREE: tuple[str, ...] = (
    "schema_version",
    "name",
    "description",
    "task",
    "limits",
    "humans",
    "sim",
    "ros2",
    "shield.mode",
    "shield.dt_s",
    "shield.max_interval_s",
    "shield.ssm",
    "shield.pfl.min_speed_scale",
    "shield.pfl.thresholds",
    "shield.pfl.overrides",
    "inputs.max_people",
    "inputs.cycle_phase_lock",
)
"""Not what the verdict assumes (the cycle's step is verified whatever its length, a longer
interval of the sets only widens them; the energy table has its own editor and guard)."""

HIGHER_LOOSENS: dict[str, str] = {
    "shield.skeleton_timeout_s": "a person's last skeleton is trusted for longer",
    "shield.tracking_tol_rad": "the robot may deviate further from its verified plan",
    "inputs.tracker_timeout_s": "a silent tracker is noticed later",
    "inputs.robot_state_timeout_s": "a silent controller is noticed later",
    "inputs.robot_rest_speed_rad_s": "a slowly moving robot is taken for one at rest",
    "inputs.cell_bound_m": "coordinates farther out are taken as measurements",
    "inputs.gate.bone_tol_m": "the tracking gate accepts bones further off their length",
    "inputs.gate.max_hold_s": "a distrusted joint is held for longer",
    "inputs.gate.stale_after_s": "a repeated skeleton is a fault later",
}
LOWER_LOOSENS: dict[str, str] = {
    "robot.margin_m": "the robot's capsules shrink",
    "inputs.low_confidence_extra_m": "low-confidence joints get smaller sets",
    "inputs.gate.recover_s": "a person beyond the set's bounds is trusted again sooner",
    "shield.jssa.d_min_m": "JSSA keeps a smaller distance",
}
OFF_LOOSENS: dict[str, str] = {
    "inputs.gate.stale_tracker": "a tracker repeating its skeletons is not noticed",
}
ON_LOOSENS: dict[str, str] = {
    "inputs.trust_stated_velocities": "a tracker's stated velocities narrow the sets: a wrong "
    "one the positions cannot contradict narrows them wrongly",
}
ADDED_LOOSENS: dict[str, str] = {
    "shield.models": "a body part is cleared when any model's set is free: one more model is "
    "one more chance to clear it",
    "shield.pfl.unclampable_pairs": "a link pair declared unable to clamp a body part",
}
REMOVED_LOOSENS: dict[str, str] = {
    "inputs.trackers": "the robot no longer waits for that tracker's frames",
}
MAX_LISTED = 8
_MISSING = object()


class LooseningRefusedError(ParameterError):
    """A scenario edit that loosens what the verdict assumes, sent without a confirmation;
    ``changes`` lists each loosening in words."""

    def __init__(self, changes: list[str], how_to_confirm: str) -> None:
        self.changes = changes
        self.audit_row: dict[str, Any] | None = None
        """The refusal's row in the audit log (:func:`apply_checked` records it)."""
        shown = "; ".join(changes[:MAX_LISTED])
        more = f" (and {len(changes) - MAX_LISTED} more)" if len(changes) > MAX_LISTED else ""
        super().__init__(
            f"this edit loosens what the safety verdict assumes: {shown}{more}; apply it only "
            f"with an explicit confirmation ({how_to_confirm}); it is recorded in the audit log"
        )


def _value(v: Any) -> str:
    return "(none)" if v is _MISSING else clipped(v, 60)


def _diffs(old: Any, new: Any, path: str) -> Iterator[tuple[str, Any, Any]]:
    """``(dotted path, old, new)`` of every differing value; objects are compared key by key
    (a key on one side only: ``_MISSING`` on the other), everything else as a whole."""
    if isinstance(old, Mapping) and isinstance(new, Mapping):
        for k in sorted(set(old) | set(new), key=str):
            yield from _diffs(old.get(k, _MISSING), new.get(k, _MISSING), f"{path}.{k}" if path
                              else str(k))  # fmt: skip
    elif old != new:
        yield path, old, new


def _rule_of(path: str, rules: Mapping[str, str] | tuple[str, ...]) -> str | None:
    """The rule key that ``path`` falls under (itself or a section above it)."""
    for key in rules:
        if path == key or path.startswith(key + "."):
            return key
    return None


def _pairs(robot: str, pairs: Any) -> set[frozenset[str]]:
    declared = ROBOT_UNCLAMPABLE_PAIRS.get(robot, ()) if pairs is None else pairs
    return {frozenset(p) for p in declared}


def _boxes(old: list[dict[str, Any]], new: list[dict[str, Any]]) -> list[str]:
    by_name = {b["name"]: b for b in new}
    out = []
    for box in old:
        other = by_name.get(box["name"])
        if other is None:
            out.append(f"environment box {box['name']!r} removed: no clamping against it")
        else:
            out.extend(
                f"environment box {box['name']!r} {path}: {_value(a)} -> {_value(b)} (the "
                "cell's clamping is checked against where it is said to be)"
                for path, a, b in _diffs(box, other, "")
            )
    return out


def _directed(path: str, old: Any, new: Any) -> list[str] | None:
    """The loosening of a field with a direction ([] when it tightens), None when ``path``
    has no direction."""
    for rules, loosens in (
        (HIGHER_LOOSENS, lambda a, b: b > a),
        (LOWER_LOOSENS, lambda a, b: b < a),
        (OFF_LOOSENS, lambda a, b: a and not b),
        (ON_LOOSENS, lambda a, b: b and not a),
    ):
        key = _rule_of(path, rules)
        if key is not None:
            if old is _MISSING or new is _MISSING or loosens(old, new):
                return [f"{path}: {_value(old)} -> {_value(new)} ({rules[key]})"]
            return []
    return None


def _listed(path: str, old: Any, new: Any, robot: tuple[str, str]) -> list[str] | None:
    """Lists whose added (or removed) items loosen; None when ``path`` is not one."""
    if path == "shield.pfl.unclampable_pairs":
        added = _pairs(robot[1], new) - _pairs(robot[0], old)
        return [f"{path}: {'/'.join(sorted(p))} added ({ADDED_LOOSENS[path]})" for p in
                sorted(added, key=sorted)]  # fmt: skip
    for rules, sign in ((ADDED_LOOSENS, 1), (REMOVED_LOOSENS, -1)):
        if path in rules:
            a = set(old) if isinstance(old, list) else set()
            b = set(new) if isinstance(new, list) else set()
            items = b - a if sign > 0 else a - b
            verb = "added" if sign > 0 else "removed"
            return [f"{path}: {x!r} {verb} ({rules[path]})" for x in sorted(items, key=str)]
    return None


def loosenings(current: Scenario | None, new: Scenario) -> list[str]:
    """Each way ``new`` loosens what the verdict of ``current`` (the scenario in force; None:
    not known, so any edit is one) assumes, in words; [] when it loosens nothing."""
    if current is None:
        return ["the scenario the cell runs is not known yet, so this edit cannot be compared "
                "with it"]  # fmt: skip
    old, data = current.model_dump(mode="json"), new.model_dump(mode="json")
    robots = (current.robot.name, new.robot.name)
    out = _boxes(old["environment"], data["environment"])
    for path, a, b in _diffs(old, data, ""):
        if path == "environment" or _rule_of(path, FREE) is not None:
            continue
        found = _listed(path, a, b, robots)
        if found is None:
            found = _directed(path, a, b)
        if found is None:
            found = [f"{path}: {_value(a)} -> {_value(b)}"]
        out.extend(found)
    return out


def check_loosening(
    current: Scenario | None, new: Scenario, *, confirm: bool, how_to_confirm: str
) -> list[str]:
    """The loosenings of ``new`` (:func:`loosenings`); :class:`LooseningRefusedError` when
    there are any and ``confirm`` is false."""
    found = loosenings(current, new)
    if found and not confirm:
        raise LooseningRefusedError(found, how_to_confirm)
    return found


def apply_checked(
    current: Scenario | None,
    new: Scenario,
    send: Callable[[bool], T],
    *,
    confirm: bool,
    how_to_confirm: str,
    audit: Callable[[], AuditLog],
    cell: str,
    user: str,
    via: str,
    no_answer: tuple[type[BaseException], ...] = (),
) -> tuple[T, list[str], dict[str, Any] | None]:
    """Check ``new`` against ``current`` (:func:`check_loosening`), then ``send(confirmed)``
    it: the edit's result, its loosenings and their audit row (None without any). An
    unconfirmed loosening is recorded and raised (:class:`LooseningRefusedError` with its
    ``audit_row``, nothing sent); a confirmed one is recorded with its outcome: ``applied``,
    ``no_answer`` (``send`` raised one of ``no_answer``: the worker may or may not have applied
    it) or ``refused`` (``send`` raised anything else, re-raised). The log is opened before
    sending: an edit that cannot be recorded is not made. ``confirmed``, passed to ``send``,
    goes to the worker with the edit, which refuses an unconfirmed loosening itself."""
    try:
        found = check_loosening(current, new, confirm=confirm, how_to_confirm=how_to_confirm)
    except LooseningRefusedError as e:
        e.audit_row = audit().record_assumption_change(
            cell=cell, scenario=new.name, changes=e.changes, confirmed=False, outcome="refused",
            user=user, via=via, reason=str(e),
        )  # fmt: skip
        raise
    if not found:
        return send(False), found, None
    log = audit()
    common: dict[str, Any] = {"cell": cell, "scenario": new.name, "changes": found,
                              "confirmed": True, "user": user, "via": via}  # fmt: skip
    try:
        result = send(True)
    except no_answer as e:
        log.record_assumption_change(**common, outcome="no_answer", reason=str(e))
        raise
    except Exception as e:
        log.record_assumption_change(**common, outcome="refused", reason=str(e))
        raise
    return result, found, log.record_assumption_change(**common, outcome="applied")
