"""A human parameter set's record of what it is sound on (``ParamSet.sound_for``, written by
``sara-app calibrate``, ``legs`` and ``displacement`` when they fitted it), in words: counts,
never more than the record says. The dashboard's Scenario tab and the evidence report show it.

The record's entries are strings; some hold JSON tables per recording. Those the calibration
writes are read as such: ``misses_per_recording`` (per recording and model, the future positions
outside the model's set: the effective set's column is what the verdict uses), ``leave_one_out``
(per recording, fitted without it: the share of future positions contained, the misses and the
unflagged ones, outside the effective set while the conformance monitor had not faulted the
person) and tables of ``[misses, unflagged]`` per recording (and per horizon). Any other entry
is given as written, shortened; a table this module cannot read is said to be one, not guessed
at."""

from __future__ import annotations

import json
from typing import Any

TEXT_LIMIT = 240
"""Characters of a free-text entry given (the rest is in the set's file; the evidence report
keeps the record whole beside its summary)."""

MARGIN_KEYS = {True: "margin_v_a_arm", False: "margin_declined_v_a_arm"}
"""The record's key for the margin leaving each recording out derives, by whether the set was
widened by it (``sara-app calibrate --leave-one-out``) or not (``--no-widen``)."""

_LABELS = {
    "models": "Models",
    "misses_per_recording": "Fitted to",
    "leave_one_out": "Each recording left out of the fit",
    "ceilings": "Ceilings",
    "reconstruction_failures_left_out": "Reconstruction failures left out",
    "margin_v_a_arm": "Margin (speeds, accelerations, arm)",
    "margin_declined_v_a_arm": "Margin it would need, not applied (speeds, accelerations, arm)",
    "legs_unmeasured_left_out_misses_unflagged_0_5s": (
        "Unmeasured legs' height bound, each left out, before the margin this gave it (0.5 s)"
    ),
    "displacement_left_out_misses_unflagged": "Displacement bound, each left out",
}
_ORDER = tuple(_LABELS)


def _n(x: int) -> str:
    return f"{x:,}".replace(",", " ")


def _fitted(table: dict[str, Any], horizon: str) -> str:
    """``misses_per_recording``: per recording ``{model: misses}``, ``effective`` among them."""
    names = list(table)
    eff = [int(v["effective"]) for v in table.values() if "effective" in v]
    by_model: dict[str, int] = {}
    for v in table.values():
        for m, k in v.items():
            if m != "effective":
                by_model[m] = by_model.get(m, 0) + int(k)
    shown = ", ".join(names[:6]) + (f" and {len(names) - 6} more" if len(names) > 6 else "")
    out = f"{len(names)} recordings ({shown})"
    if len(eff) == len(names):
        out += f"; the effective set misses {_n(sum(eff))} future positions of them{horizon}"
    worst = {m: k for m, k in by_model.items() if k}
    if worst:
        out += "; models: " + ", ".join(f"{m} {_n(k)}" for m, k in worst.items())
    elif by_model:
        out += "; every model contains them"
    return out


def _left_out(table: dict[str, Any], horizon: str) -> str:
    """``leave_one_out``: per recording ``{share, misses, unflagged}``."""
    whole = sum(1 for v in table.values() if float(v["share"]) >= 1.0)
    misses = sum(int(v["misses"]) for v in table.values())
    unflagged = sum(int(v["unflagged"]) for v in table.values())
    return (
        f"{whole} of {len(table)} contained whole{horizon}; {_n(misses)} future positions "
        f"outside the effective set, {_n(unflagged)} of them unflagged (the monitor had not "
        "faulted the person)"
    )


def _pairs(table: dict[str, Any]) -> str:
    """Tables of ``[misses, unflagged]`` per recording, or per recording and horizon."""
    per: dict[str, list[int]] = {}
    for v in table.values():
        items = v.items() if isinstance(v, dict) else [("", v)]
        for h, (m, u) in items:
            acc = per.setdefault(str(h), [0, 0])
            acc[0] += int(m)
            acc[1] += int(u)
    parts = [f"{h}: " * bool(h) + f"{_n(m)} misses, {_n(u)} unflagged" for h, (m, u) in per.items()]
    return f"{len(table)} recordings; " + "; ".join(parts)


def _entry(key: str, text: str, horizon: str) -> str:
    """One entry in words (see the module notes)."""
    if key in ("misses_per_recording", "leave_one_out") or text.lstrip().startswith("{"):
        try:
            table = json.loads(text)
            if key == "misses_per_recording":
                return _fitted(table, horizon)
            if key == "leave_one_out":
                return _left_out(table, horizon)
            return _pairs(table)
        except (ValueError, TypeError, KeyError, AttributeError):
            return f"a table of {len(text)} characters (in the set's file)"
    return short(text)


def short(text: str) -> str:
    """``text`` cut to :data:`TEXT_LIMIT` characters."""
    return text if len(text) <= TEXT_LIMIT else text[: TEXT_LIMIT - 3] + "..."


def summary(record: dict[str, str]) -> list[tuple[str, str]]:
    """``(what, on the recordings)`` per entry of ``record`` (a set's ``sound_for``), the
    calibration's entries first; the horizon is said with the counts it applies to."""
    h = record.get("horizon_s", "")
    horizon = f" within {h} s" if h else ""
    keys = [k for k in _ORDER if k in record] + [k for k in record if k not in _LABELS]
    rows = []
    for k in keys:
        if k == "horizon_s":
            continue
        label = _LABELS.get(k, k.replace("_", " ").capitalize())
        if k == "leave_one_out" and "margin_v_a_arm" in record:  # the folds had no margin
            label += ", fitted without the margin this gave the set"
        rows.append((label, _entry(k, record[k], horizon)))
    return rows
