"""Threshold edits: value domain, confirmation above the source's value, overrides produced
(added, replaced, removed when back at the source value), the effective table, and the
plan-send-record sequence shared by the API and the dashboard."""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Any

import pytest

from sara_app.errors import ParameterError, ScenarioError, UnknownNameError
from sara_app.ops.audit import AuditLog
from sara_app.ops.threshold_edit import (
    ConfirmationRequired,
    apply_edit,
    check_energy,
    plan_edit,
    threshold_view,
)
from sara_app.safety.thresholds import CONTACTS, REGIONS, SHAPES, load_thresholds
from sara_app.scenario import Scenario, load_scenario, parse_scenario

SEED = load_thresholds("thresholds_thumm2024")
ENTRIES = list(itertools.product(REGIONS, CONTACTS, SHAPES))


@pytest.fixture(scope="module")
def sc() -> Scenario:
    return load_scenario("empty_cell")


def _with(sc: Scenario, data: dict[str, Any]) -> Scenario:
    return parse_scenario(data)


@pytest.mark.parametrize("bad", [0.0, -0.1, math.nan, math.inf, -math.inf, "1", None, True])
def test_energy_domain(sc: Scenario, bad: object) -> None:
    with pytest.raises(ParameterError, match=r"finite number > 0 J") as e:
        check_energy(bad)
    assert repr(bad)[:3] in str(e.value) or str(bad) in str(e.value)
    with pytest.raises(ParameterError, match="finite number > 0 J"):
        plan_edit(sc, "hand", "constrained", "blunt", bad, confirm=True)


def test_unknown_names_list_the_choices(sc: Scenario) -> None:
    with pytest.raises(UnknownNameError, match="torso_legs"):
        plan_edit(sc, "elbow", "constrained", "blunt", 0.1)
    with pytest.raises(UnknownNameError, match="unconstrained"):
        plan_edit(sc, "hand", "clamped", "blunt", 0.1)
    with pytest.raises(UnknownNameError, match="sheet"):
        plan_edit(sc, "hand", "constrained", "round", 0.1)


@pytest.mark.parametrize("entry", ENTRIES[::3])
def test_above_source_needs_confirmation_below_does_not(sc: Scenario, entry: tuple) -> None:
    src = SEED.limit(*entry)
    with pytest.raises(ConfirmationRequired) as e:
        plan_edit(sc, *entry, src.energy_J * 1.5)
    msg = str(e.value)
    assert src.source in msg and f"{src.energy_J:g} J" in msg and "confirm" in msg
    assert SEED.sources[src.source] in msg
    assert e.value.plan.exceeds_source and not e.value.plan.confirmed
    plan = plan_edit(sc, *entry, src.energy_J * 1.5, confirm=True)
    assert plan.exceeds_source and plan.confirmed and plan.new_energy_J == src.energy_J * 1.5
    low = plan_edit(sc, *entry, src.energy_J * 0.5)
    assert not low.exceeds_source and low.warning == ""
    assert low.old_energy_J == src.energy_J and low.source_energy_J == src.energy_J


def test_overrides_added_replaced_removed(sc: Scenario) -> None:
    entry = ("hand", "constrained", "blunt")
    src = SEED.energy_J(*entry)
    p1 = plan_edit(sc, *entry, 0.08)
    ov = p1.data["shield"]["pfl"]["overrides"]
    assert ov == [{"region": "hand", "contact": "constrained", "shape": "blunt", "energy_J": 0.08}]
    sc1 = _with(sc, p1.data)
    p2 = plan_edit(sc1, "head", "unconstrained", "edge", 0.05)
    sc2 = _with(sc, p2.data)
    assert len(sc2.shield.pfl.overrides) == 2
    p3 = plan_edit(sc2, *entry, 0.09)  # replaced in place, not duplicated
    sc3 = _with(sc, p3.data)
    assert p3.old_energy_J == 0.08
    assert [(o.region, o.energy_J) for o in sc3.shield.pfl.overrides] == [
        ("hand", 0.09),
        ("head", 0.05),
    ]
    p4 = plan_edit(sc3, *entry, src)  # back to the source: the override goes
    assert p4.removes_override and not p4.exceeds_source
    sc4 = _with(sc, p4.data)
    assert [o.region for o in sc4.shield.pfl.overrides] == ["head"]
    # nothing else in the scenario changed
    a, b = sc.model_dump(mode="json"), sc4.model_dump(mode="json")
    a["shield"]["pfl"]["overrides"] = b["shield"]["pfl"]["overrides"] = []
    assert a == b


def test_view_is_the_effective_table(sc: Scenario) -> None:
    p = plan_edit(sc, "lower_arm", "unconstrained", "blunt", 2.0, confirm=True)
    view = threshold_view(_with(sc, p.data))
    rows = view["entries"]
    assert len(rows) == len(ENTRIES) == 40
    assert [(r["region"], r["contact"], r["shape"]) for r in rows] == ENTRIES
    for r in rows:
        src = SEED.limit(r["region"], r["contact"], r["shape"])
        assert r["source_energy_J"] == src.energy_J and r["source_key"] == src.source
        assert r["source_text"] == SEED.sources[src.source]
        edited = (r["region"], r["contact"], r["shape"]) == ("lower_arm", "unconstrained", "blunt")
        assert r["overridden"] == edited == r["exceeds_source"]
        assert r["energy_J"] == (2.0 if edited else src.energy_J)
        assert r["iso_reference"], r
    head = next(r for r in rows if r["region"] == "head" and r["contact"] == "constrained")
    iso = {x["iso_region"]: x for x in head["iso_reference"]}
    assert set(iso) == {"skull_forehead", "face", "neck"}
    assert iso["face"]["energy_J"] == pytest.approx(65.0**2 / (2 * 75e3))  # E = F^2 / (2 k)
    free = next(r for r in rows if r["region"] == "hand" and r["contact"] == "unconstrained")
    assert free["iso_reference"][0]["energy_J"] == pytest.approx(4 * 140.0**2 / (2 * 75e3))
    assert view["thresholds"] == "thresholds_thumm2024" and view["safety_mode"] == "ssm"


def test_apply_records_every_outcome(sc: Scenario, tmp_path: Path) -> None:
    audit = AuditLog(tmp_path / "a.sqlite")
    sent: list[dict[str, Any]] = []
    entry = ("hand", "unconstrained", "blunt")
    src = SEED.limit(*entry)

    def ok(data: dict[str, Any]) -> None:
        sent.append(data)

    def refuse(data: dict[str, Any]) -> None:
        raise ScenarioError("the worker refused it: busy")

    def silent(data: dict[str, Any]) -> None:
        raise TimeoutError("no answer within 3 s")

    kw: dict[str, Any] = {"audit": audit, "cell": "c1", "user": "ana", "via": "test"}
    plan, row = apply_edit(sc, *entry, 0.3, confirm=False, send=ok, **kw)
    assert sent == [plan.data] and row.outcome == "applied" and row.new_energy_J == 0.3
    assert row.old_energy_J == src.energy_J and row.source_key == src.source
    with pytest.raises(ConfirmationRequired):
        apply_edit(sc, *entry, 9.0, confirm=False, send=ok, **kw)
    with pytest.raises(ParameterError):
        apply_edit(sc, *entry, -1.0, confirm=False, send=ok, **kw)
    with pytest.raises(UnknownNameError):
        apply_edit(sc, "nose", "constrained", "blunt", 0.1, confirm=False, send=ok, **kw)
    with pytest.raises(ScenarioError):
        apply_edit(sc, *entry, 0.2, confirm=False, send=refuse, **kw)
    with pytest.raises(TimeoutError):
        apply_edit(sc, *entry, 0.2, confirm=False, send=silent, no_answer=(TimeoutError,), **kw)
    assert len(sent) == 1  # only the first edit was sent
    rows = audit.entries("c1")
    assert [r.outcome for r in rows] == [
        "no_answer",
        "refused",
        "refused",
        "refused",
        "refused",
        "applied",
    ]
    conf, neg, nose = rows[4], rows[3], rows[2]
    assert conf.exceeds_source and not conf.confirmed and "confirm" in conf.reason
    assert neg.new_energy_J == -1.0 and neg.requested == "-1.0" and "> 0 J" in neg.reason
    assert neg.source_energy_J == src.energy_J  # known entry: its values are recorded
    assert nose.region == "nose" and nose.source_key is None and "valid choices" in nose.reason
    assert "busy" in rows[1].reason and "no answer" in rows[0].reason
    with pytest.raises(ParameterError):
        apply_edit(sc, *entry, math.nan, confirm=False, send=ok, **kw)
    nan = audit.entries("c1", limit=1)[0]
    assert nan.new_energy_J is None and nan.requested == "nan" and nan.outcome == "refused"
    assert {r.user for r in rows} == {"ana"} and {r.via for r in rows} == {"test"}
