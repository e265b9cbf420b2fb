"""What a client's scenario edit may not do on its own (the API's scenario routes, the
dashboard's Scenario tab, a what-if's *Apply*).

- **Read a file of the server's choosing.** A scenario names a robot, recordings, a human
  parameter set and a threshold set; the loaders also take file paths, which a cell configured on
  the server's command line may use. From a client (over the network) only shipped names are
  taken, a parameter set may come inline, and a path is taken only when the cell already uses
  it: otherwise a threshold-set path loaded a table of 500 J limits past the editor's ceiling,
  its confirmation and its audit, and a path to the API's token file answered with the tokens
  in the validation error (hostile-user probe, 2026-11-30). :func:`file_references` reads the
  request's JSON before anything is loaded.
- **Raise a contact-energy limit in force.** Only the threshold editor does
  (:func:`sara_app.ops.threshold_edit.apply_edit`: a confirmation above the source value, every
  outcome audited). A scenario edit that would raise an entry of the table in force, by a new
  override, another set, or by dropping an override that tightened it (a partial edit that
  replaced the overrides did), is refused naming the entries (:func:`raised_energies`);
  lowering one is a tightening and passes.

:func:`check_client_edit` applies the first (before validation), :func:`check_no_raise` the
second; :class:`EditRefusedError` names what was refused and
where the change is made instead.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sara_app.errors import ParameterError, clipped
from sara_app.human.params import RENAMED as PARAM_SETS_RENAMED
from sara_app.human.params import available_param_sets
from sara_app.ops.threshold_edit import effective_energy
from sara_app.robot.model import robot_names
from sara_app.safety.thresholds import (
    CONTACTS,
    DEFAULT_SET,
    REGIONS,
    SHAPES,
    load_thresholds,
    threshold_set_names,
)
from sara_app.safety.thresholds import RENAMED as THRESHOLDS_RENAMED
from sara_app.scenario import Scenario

_RECORDING_NAME = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*(/[A-Za-z0-9_][A-Za-z0-9_.\-]*)*")
"""A recording's name (``02_01``, ``CollaborativeHammering/0``): resolved inside the data
folders only, never ``..``, never absolute."""


class EditRefusedError(ParameterError):
    """A client's scenario edit that only the server's configuration or the threshold editor
    may make."""


def _is_recording_name(value: str) -> bool:
    return (
        _RECORDING_NAME.fullmatch(value) is not None
        and ".." not in value.split("/")
        and not Path(value).is_file()  # a file beside the server's working directory is a path
    )


def file_references(data: Any) -> dict[str, str]:
    """``{field: value}`` of every value in scenario ``data`` (JSON, as a client sends it, not
    validated yet) that refers to a file rather than naming a shipped item: ``robot.name``,
    ``human_params``, ``shield.pfl.thresholds``, ``humans.<i>.recording``. Nothing is read."""
    out: dict[str, str] = {}
    if not isinstance(data, Mapping):
        return out
    robot = data.get("robot")
    name = robot.get("name") if isinstance(robot, Mapping) else None
    if isinstance(name, str) and name not in robot_names():
        out["robot.name"] = name
    hp = data.get("human_params")
    if isinstance(hp, str) and PARAM_SETS_RENAMED.get(hp, hp) not in available_param_sets():
        out["human_params"] = hp
    shield = data.get("shield")
    pfl = shield.get("pfl") if isinstance(shield, Mapping) else None
    th = pfl.get("thresholds") if isinstance(pfl, Mapping) else None
    if isinstance(th, str) and THRESHOLDS_RENAMED.get(th, th) not in threshold_set_names():
        out["shield.pfl.thresholds"] = th
    humans = data.get("humans")
    for i, h in enumerate(humans if isinstance(humans, list) else ()):
        rec = h.get("recording") if isinstance(h, Mapping) else None
        if isinstance(rec, str) and not _is_recording_name(rec):
            out[f"humans.{i}.recording"] = rec
    return out


def raised_energies(current: Scenario | None, new: Scenario) -> list[str]:
    """The entries (``region/contact/shape a -> b J``) whose contact-energy limit ``new`` puts
    above the one in force in ``current`` (None: the shipped set's values, without edits)."""
    base_new = new.shield.pfl.source_set()
    base_cur = load_thresholds(DEFAULT_SET) if current is None else current.shield.pfl.source_set()
    out = []
    for entry in ((r, c, s) for r in REGIONS for c in CONTACTS for s in SHAPES):
        if current is None:
            before = float(base_cur.energy_J(*entry))
        else:
            before = effective_energy(current, base_cur, entry)[0]
        after = effective_energy(new, base_new, entry)[0]
        if after > before:
            out.append(f"{'/'.join(entry)} {before:g} -> {after:g} J")
    return out


def check_client_edit(current_data: Mapping[str, Any] | None, new_data: Any) -> None:
    """Refuse (:class:`EditRefusedError`) a client's scenario ``new_data`` that refers to a file
    the cell's scenario ``current_data`` (JSON; None: none known) does not already use. Call it
    before validating ``new_data`` (validation loads the named files)."""
    allowed = set(file_references(current_data).values()) if current_data is not None else set()
    bad = {k: v for k, v in file_references(new_data).items() if v not in allowed}
    if bad:
        field, value = next(iter(bad.items()))
        raise EditRefusedError(
            f"{field} = {clipped(value)} refers to a file on the server; an edit from a client "
            f"names a shipped item (robots: {', '.join(robot_names())}; parameter sets: "
            f"{', '.join(available_param_sets())}; threshold sets: "
            f"{', '.join(threshold_set_names())}; recordings by name) or sends a parameter "
            "set inline; files are chosen where the cell is started"
            + (f" (and {len(bad) - 1} more)" if len(bad) > 1 else "")
        )


def check_no_raise(current: Scenario | None, new: Scenario, *, thresholds_path: str) -> None:
    """Refuse (:class:`EditRefusedError`) a scenario edit that raises a contact-energy limit
    in force (:func:`raised_energies`): only the threshold editor ``thresholds_path`` does."""
    raised = raised_energies(current, new)
    if raised:
        more = f" (and {len(raised) - 3} more)" if len(raised) > 3 else ""
        raise EditRefusedError(
            f"this edit raises the contact-energy limit {'; '.join(raised[:3])}{more}; limits "
            f"are raised only in the threshold editor ({thresholds_path}), which asks for a "
            "confirmation above the source value and audits it"
        )
