"""The dashboard's threshold editor on a real viser server (127.0.0.1, no browser): its GUI
callbacks validate, ask for confirmation above the source value, send through the callable it
was given, and record every outcome in the same audit log as the REST service."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import viser

from sara_app.bus.session import free_port
from sara_app.dashboard.thresholds_panel import ThresholdsPanel, attach, audit_markdown
from sara_app.errors import ScenarioError
from sara_app.ops.audit import AuditLog
from sara_app.safety.thresholds import load_thresholds
from sara_app.scenario import Scenario, check_against_robot, load_scenario, parse_scenario

SEED = load_thresholds("thresholds_thumm2024")


class StandInCell:
    """Holds the scenario like ``CellView``: ``send`` validates, may refuse, keeps on accept."""

    def __init__(self) -> None:
        self.scenario = load_scenario("empty_cell")
        self.refuse: str | None = None
        self.sent: list[dict[str, Any]] = []

    def get(self) -> Scenario:
        return self.scenario

    def send(self, data: dict[str, Any]) -> Scenario:
        sc = parse_scenario(data, "edited scenario")
        check_against_robot(sc)
        self.sent.append(data)
        if self.refuse:
            raise ScenarioError(f"the worker refused it: {self.refuse}")
        self.scenario = sc
        return sc


@pytest.fixture(scope="module")
def server() -> Iterator[viser.ViserServer]:
    s = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    yield s
    s.stop()


@pytest.fixture
def panel(
    server: viser.ViserServer, tmp_path: Path
) -> Iterator[tuple[ThresholdsPanel, StandInCell, AuditLog]]:
    cell = StandInCell()
    audit = AuditLog(tmp_path / "audit.sqlite")
    p = attach(server.gui, cell.get, cell.send, audit, "c1", user="eng")
    yield p, cell, audit
    p.folder.remove()


def _click(p: ThresholdsPanel) -> None:
    p.apply_button.value = True  # a button "value" assignment runs its click callbacks


def test_selecting_an_entry_shows_its_source(
    panel: tuple[ThresholdsPanel, StandInCell, AuditLog],
) -> None:
    p, _, _ = panel
    assert p.entry() == ("hand", "constrained", "blunt")
    assert p.energy.value == SEED.energy_J("hand", "constrained", "blunt")
    p.region.value = "head"
    p.contact.value = "unconstrained"
    p.shape.value = "edge"  # each dropdown change re-selects
    src = SEED.limit("head", "unconstrained", "edge")
    assert p.energy.value == src.energy_J
    assert f"{src.energy_J:g} J" in p.source.content and src.source in p.source.content
    assert SEED.sources[src.source] in p.source.content
    assert "skull_forehead" in p.source.content  # ISO/TS 15066 reference beside
    assert "safety mode **ssm**" in p.header.content and "empty_cell" in p.header.content
    assert not p.warning.visible and not p.confirm.visible
    assert "No threshold changes" in p.history.content


def test_apply_confirm_refuse_and_audit(
    panel: tuple[ThresholdsPanel, StandInCell, AuditLog],
) -> None:
    p, cell, audit = panel
    src = SEED.energy_J("hand", "constrained", "blunt")
    p.energy.value = 0.1
    _click(p)
    assert cell.scenario.shield.pfl.overrides[0].energy_J == 0.1
    assert "0.12 → 0.1 J applied" in p.message.content
    assert "In force: **0.1 J** (edited)" in p.source.content
    # the table of every value in force opens with the tab, the edit in bold beside its source
    assert p.folder.expand_by_default
    assert "| hand, constrained | **0.1** (0.12) |" in p.table.content
    head = SEED.energy_J("head", "unconstrained", "blunt")
    assert f"| head, unconstrained | {head:g} |" in p.table.content
    # above the source: the warning and the checkbox appear as soon as the value is typed
    p.energy.value = 0.3
    assert p.warning.visible and p.confirm.visible and f"{src:g} J" in p.warning.content
    n = len(cell.sent)
    _click(p)  # not confirmed: refused before anything is sent
    assert len(cell.sent) == n and "confirm" in p.message.content
    assert "iso15066" in p.warning.content  # the full warning names the source
    p.confirm.value = True
    _click(p)
    assert cell.scenario.shield.pfl.overrides[0].energy_J == 0.3
    assert not p.confirm.value  # the confirmation is not kept for the next edit
    # invalid value: refused with the valid range, nothing sent
    p.energy.value = 0.0
    n = len(cell.sent)
    _click(p)
    assert len(cell.sent) == n and "> 0 J" in p.message.content
    # the worker refuses: the scenario stays as it was
    cell.refuse = "robot busy"
    p.energy.value = 0.11
    _click(p)
    assert "robot busy" in p.message.content
    assert cell.scenario.shield.pfl.overrides[0].energy_J == 0.3
    cell.refuse = None
    # back at the source value: override removed
    p.energy.value = src
    _click(p)
    assert cell.scenario.shield.pfl.overrides == [] and "override removed" in p.message.content
    rows = audit.entries("c1")
    assert [r.outcome for r in rows] == [
        "applied",
        "refused",
        "refused",
        "applied",
        "refused",
        "applied",
    ]
    assert {r.via for r in rows} == {"dashboard"} and {r.user for r in rows} == {"eng"}
    assert rows[3].exceeds_source and rows[3].confirmed
    assert rows[4].exceeds_source and not rows[4].confirmed
    assert p.history.content == audit_markdown(rows[:8])
    assert p.history.content.count("\n") == len(rows) + 1  # header, rule, one line per row


def test_audit_markdown_flags_and_outcomes(tmp_path: Path) -> None:
    log = AuditLog(tmp_path / "a.sqlite")
    log.record(
        cell="c",
        scenario="s",
        entry=("hand", "constrained", "blunt"),
        requested=float("inf"),
        outcome="refused",
        reason="x",
        user="bo",
    )
    log.record(
        cell="c",
        scenario="s",
        entry=("head", "constrained", "edge"),
        requested=0.5,
        old_energy_J=0.0275,
        exceeds_source=True,
        confirmed=True,
        outcome="applied",
    )
    text = audit_markdown(log.entries("c"))
    lines = text.splitlines()
    assert "0.0275 → 0.5 ⚠" in lines[2] and "| applied |" in lines[2]
    assert "– → inf" in lines[3] and "**refused**" in lines[3] and "| bo |" in lines[3]
