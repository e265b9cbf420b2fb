"""Editing a cell's contact-energy thresholds (Thumm et al. 2024 Table I) through its scenario.

A scenario's PFL thresholds are a named set (``shield.pfl.thresholds``, e.g.
``thresholds_thumm2024``) plus ``shield.pfl.overrides``: the entries the safety engineer changed.
Every entry has a *source*: the set's value and the key of the publication it comes from. An
edit is a new scenario with a changed ``overrides`` list, sent to the worker like any other
scenario edit (validated, acknowledged, never half-applied).

- :func:`check_energy`: the value must be a finite number > 0 J (ParameterError otherwise,
  naming the value and the valid range).
- :func:`plan_edit`: validates one edit against the scenario. A value above the entry's source
  value raises :class:`ConfirmationRequired` (naming the source and its value) unless
  ``confirm=True``. The plan carries the new scenario as JSON data; setting an entry back to its
  source value removes its override.
- :func:`apply_edit`: plan, send (a callable given by the caller: the API's or the dashboard's
  path to the worker) and record every outcome in the audit log; the API and the dashboard
  both use it, so they validate and record identically.
- :func:`threshold_view`: the effective table (value, source value, source, overridden flag and
  the ISO/TS 15066 Annex A reference values of the region, for display only).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

from sara_app.errors import ParameterError, SaraError, UnknownNameError
from sara_app.ops.audit import AuditEntry, AuditLog
from sara_app.safety.settings import MAX_THRESHOLD_J
from sara_app.safety.thresholds import (
    CONTACTS,
    REGIONS,
    SHAPES,
    ThresholdSet,
)
from sara_app.scenario import Scenario, parse_scenario

ENERGY_RANGE = f"a finite number > 0 J and <= {MAX_THRESHOLD_J:g} J (the physical ceiling)"

ISO_REGIONS: dict[str, tuple[str, ...]] = {
    "hand": ("hand",),
    "lower_arm": ("lower_arm",),
    "upper_arm": ("upper_arm",),
    "torso_legs": ("back_shoulders", "chest", "abdomen", "pelvis", "thigh", "lower_leg"),
    "head": ("skull_forehead", "face", "neck"),
}
"""Thumm et al. 2024 Table I region -> the ISO/TS 15066 Annex A body regions it covers
(reference)."""

Entry = tuple[str, str, str]


def check_entry(region: str, contact: str, shape: str) -> Entry:
    """``(region, contact, shape)`` when each is a valid Table I name; UnknownNameError else."""
    for kind, name, valid in (
        ("body region", region, REGIONS),
        ("contact type", contact, CONTACTS),
        ("contact shape", shape, SHAPES),
    ):
        if name not in valid:
            raise UnknownNameError(kind, str(name), valid)
    return region, contact, shape


def check_energy(energy_J: object) -> float:
    """``energy_J`` as a float when it is a finite number > 0; ParameterError otherwise."""
    if isinstance(energy_J, bool) or not isinstance(energy_J, int | float):
        raise ParameterError(
            f"threshold energy {energy_J!r} is not a number; expected {ENERGY_RANGE}"
        )
    value = float(energy_J)
    if not math.isfinite(value) or value <= 0.0 or value > MAX_THRESHOLD_J:
        raise ParameterError(
            f"threshold energy {value!r} J is out of range; expected {ENERGY_RANGE}"
        )
    return value


def effective_energy(sc: Scenario, base: ThresholdSet, entry: Entry) -> tuple[float, bool]:
    """The value in force for ``entry`` and whether it is an override."""
    for o in sc.shield.pfl.overrides:
        if (o.region, o.contact, o.shape) == entry:
            return float(o.energy_J), True
    return float(base.energy_J(*entry)), False


class ConfirmationRequired(ParameterError):
    """The requested value exceeds the source's value: apply only with ``confirm=True``."""

    def __init__(self, plan: EditPlan) -> None:
        self.plan = plan
        self.audit_entry: AuditEntry | None = None  # set by apply_edit once recorded
        super().__init__(plan.warning)


@dataclass(frozen=True)
class EditPlan:
    """One validated threshold edit; ``data`` is the whole new scenario (JSON-ready)."""

    scenario: str
    thresholds: str
    region: str
    contact: str
    shape: str
    old_energy_J: float
    new_energy_J: float
    source_energy_J: float
    source_key: str
    source_text: str
    exceeds_source: bool
    confirmed: bool
    removes_override: bool
    data: dict[str, Any]

    @property
    def entry(self) -> Entry:
        return self.region, self.contact, self.shape

    @property
    def warning(self) -> str:
        """The text shown when the value exceeds its source (empty otherwise)."""
        if not self.exceeds_source:
            return ""
        return (
            f"{'/'.join(self.entry)}: {self.new_energy_J:g} J exceeds the source value "
            f"{self.source_energy_J:g} J of {self.source_key} ({self.source_text}) in "
            f"{self.thresholds}; apply it only with an explicit confirmation (confirm=true)"
        )

    def summary(self) -> dict[str, Any]:
        """Everything but the scenario data."""
        out = asdict(self)
        del out["data"]
        out["warning"] = self.warning
        return out


def _new_overrides(sc: Scenario, entry: Entry, value: float, remove: bool) -> list[dict[str, Any]]:
    out: list[dict[str, Any]] = []
    placed = remove
    for o in sc.shield.pfl.overrides:
        if (o.region, o.contact, o.shape) != entry:
            out.append(o.model_dump(mode="json"))
        elif not placed:
            out.append({**o.model_dump(mode="json"), "energy_J": value})
            placed = True
    if not placed:
        out.append(
            dict(zip(("region", "contact", "shape"), entry, strict=True)) | {"energy_J": value}
        )
    return out


def plan_edit(
    sc: Scenario, region: str, contact: str, shape: str, energy_J: object, confirm: bool = False
) -> EditPlan:
    """Validate one edit of ``sc``'s thresholds (see the module docstring).

    Raises UnknownNameError (bad region/contact/shape), ParameterError (value not finite or not
    > 0) or ConfirmationRequired (value above the source's value without ``confirm``)."""
    entry = check_entry(region, contact, shape)
    value = check_energy(energy_J)
    base = sc.shield.pfl.source_set()
    src = base.limit(*entry)
    old, _ = effective_energy(sc, base, entry)
    remove = math.isclose(value, src.energy_J, rel_tol=1e-12, abs_tol=0.0)
    data = sc.model_dump(mode="json")
    data["shield"]["pfl"]["overrides"] = _new_overrides(sc, entry, value, remove)
    new = parse_scenario(data, "threshold edit")  # ScenarioError if anything else is off
    exceeds = bool(value > src.energy_J) and not remove
    plan = EditPlan(
        scenario=sc.name,
        thresholds=base.name,
        region=region,
        contact=contact,
        shape=shape,
        old_energy_J=old,
        new_energy_J=value,
        source_energy_J=float(src.energy_J),
        source_key=src.source,
        source_text=base.sources[src.source],
        exceeds_source=exceeds,
        confirmed=bool(confirm),
        removes_override=remove,
        data=new.model_dump(mode="json"),
    )
    if exceeds and not confirm:
        raise ConfirmationRequired(plan)
    return plan


def _iso_reference(base: ThresholdSet, region: str, contact: str) -> list[dict[str, Any]]:
    iso = base.iso_ts_15066_annex_a
    if iso is None:
        return []
    out = []
    for name in ISO_REGIONS[region]:
        r = iso.regions.get(name)
        if r is None:
            continue
        # clamping is quasi-static contact; a free collision is transient (force 2 F)
        e = r.energy_J if contact == "constrained" else r.transient_energy_J
        out.append(
            {
                "iso_region": name,
                "force_N": r.force_quasi_static_N * (1.0 if contact == "constrained" else 2.0),
                "spring_k_N_per_mm": r.spring_k_N_per_mm,
                "energy_J": e,
            }
        )
    return out


def threshold_view(sc: Scenario) -> dict[str, Any]:
    """The effective table of ``sc``: one row per Table I entry (region, contact, shape) with
    ``energy_J`` (in force), ``source_energy_J``, ``source_key``, ``source_text``,
    ``overridden`` and ``iso_reference`` (ISO/TS 15066 Annex A, for display only)."""
    base = sc.shield.pfl.source_set()
    rows = []
    for region in REGIONS:
        for contact in CONTACTS:
            for shape in SHAPES:
                src = base.limit(region, contact, shape)
                value, overridden = effective_energy(sc, base, (region, contact, shape))
                rows.append(
                    {
                        "region": region,
                        "contact": contact,
                        "shape": shape,
                        "energy_J": value,
                        "source_energy_J": float(src.energy_J),
                        "source_key": src.source,
                        "source_text": base.sources[src.source],
                        "overridden": overridden,
                        "exceeds_source": value > src.energy_J,
                        "iso_reference": _iso_reference(base, region, contact),
                    }
                )
    iso = base.iso_ts_15066_annex_a
    return {
        "scenario": sc.name,
        "safety_mode": sc.shield.mode,
        "thresholds": base.name,
        "sources": dict(base.sources),
        "iso_reference_note": None if iso is None else iso.source,
        "entries": rows,
    }


def _known_values(sc: Scenario, region: str, contact: str, shape: str) -> dict[str, Any]:
    """Old and source values of an entry for the audit of an invalid request (none if the
    entry itself is invalid)."""
    try:
        entry = check_entry(region, contact, shape)
        base = sc.shield.pfl.source_set()
    except SaraError:
        return {}
    src = base.limit(*entry)
    old, _ = effective_energy(sc, base, entry)
    return {"old_energy_J": old, "source_energy_J": src.energy_J, "source_key": src.source}


def apply_edit(
    sc: Scenario,
    region: str,
    contact: str,
    shape: str,
    energy_J: object,
    *,
    confirm: bool,
    send: Callable[[dict[str, Any]], object],
    audit: AuditLog,
    cell: str,
    user: str = "unknown",
    via: str = "api",
    no_answer: tuple[type[BaseException], ...] = (),
) -> tuple[EditPlan, AuditEntry]:
    """Plan the edit, ``send(new scenario data)`` (raises when the worker refuses or does not
    answer) and record the outcome; every refusal is recorded, then re-raised.

    Outcomes: ``applied`` (send returned), ``refused`` (invalid, unconfirmed or refused by the
    worker) and ``no_answer`` (``send`` raised one of ``no_answer``: the worker may or may not
    have applied it)."""
    common: dict[str, Any] = {"cell": cell, "user": user, "via": via, "confirmed": bool(confirm)}
    try:
        plan = plan_edit(sc, region, contact, shape, energy_J, confirm)
    except ConfirmationRequired as e:
        e.audit_entry = _record(audit, e.plan, outcome="refused", reason=str(e), **common)
        raise
    except SaraError as e:
        audit.record(
            scenario=sc.name,
            entry=(str(region), str(contact), str(shape)),
            requested=energy_J,
            outcome="refused",
            reason=str(e),
            **_known_values(sc, region, contact, shape),
            **common,
        )
        raise
    try:
        send(plan.data)
    except no_answer as e:
        _record(audit, plan, outcome="no_answer", reason=str(e), **common)
        raise
    except Exception as e:
        _record(audit, plan, outcome="refused", reason=str(e), **common)
        raise
    return plan, _record(audit, plan, outcome="applied", **common)


def _record(
    audit: AuditLog,
    plan: EditPlan,
    *,
    cell: str,
    outcome: str,
    reason: str = "",
    confirmed: bool = False,
    user: object = "unknown",
    via: str = "api",
) -> AuditEntry:
    """Record a validated (or confirmation-pending) edit plan and its outcome."""
    return audit.record(
        cell=cell,
        scenario=plan.scenario,
        entry=plan.entry,
        requested=plan.new_energy_J,
        outcome=outcome,
        reason=reason,
        old_energy_J=plan.old_energy_J,
        source_energy_J=plan.source_energy_J,
        source_key=plan.source_key,
        exceeds_source=plan.exceeds_source,
        confirmed=confirmed,
        user=user,
        via=via,
    )
