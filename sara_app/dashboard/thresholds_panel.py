"""The safety engineer's threshold editor in the viser dashboard (Thumm et al. 2024 Table I
entries).

``attach(gui, get_scenario, send, audit, cell) -> ThresholdsPanel`` adds a "Thresholds" folder:
dropdowns for the body region, contact type and shape, the value in force beside its source's
value (and the ISO/TS 15066 reference), a number input, a user field, an "Apply" button, a
"Confirm above source value" checkbox shown with the warning when the value exceeds the source,
a message line and the latest audit rows of the cell.

Validation, sending and recording are those of the REST service
(:func:`sara_app.ops.threshold_edit.apply_edit`): ``send(new scenario data)`` is the caller's
path to the worker (e.g. ``CellView.send``: it raises when the worker refuses or does not
answer, and returns the accepted scenario); ``get_scenario()`` returns the scenario the cell runs.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

import viser

from sara_app.dashboard.access import on_event
from sara_app.errors import SaraError
from sara_app.ops.audit import AuditEntry, AuditLog
from sara_app.ops.threshold_edit import (
    ConfirmationRequired,
    apply_edit,
    effective_energy,
    threshold_view,
)
from sara_app.safety.settings import mode_facts
from sara_app.safety.thresholds import CONTACTS, REGIONS, SHAPES
from sara_app.scenario import Scenario

log = logging.getLogger("sara_app.dashboard")
AUDIT_ROWS = 8


def audit_markdown(rows: Sequence[AuditEntry]) -> str:
    """The latest audit rows as a markdown table (time, entry, old -> new, outcome, user)."""
    if not rows:
        return "*No threshold changes recorded for this cell yet.*"
    lines = ["| time (UTC) | entry | old → new [J] | outcome | user |", "|---|---|---|---|---|"]
    for r in rows:
        old = "–" if r.old_energy_J is None else f"{r.old_energy_J:g}"
        new = r.requested if r.new_energy_J is None else f"{r.new_energy_J:g}"
        flag = " ⚠" if r.exceeds_source else ""
        outcome = r.outcome if r.outcome == "applied" else f"**{r.outcome}**"
        lines.append(
            f"| {r.time_utc[:19].replace('T', ' ')} | {r.region}/{r.contact}/{r.shape} | "
            f"{old} → {new}{flag} | {outcome} | {r.user} |"
        )
    return "\n".join(lines)


class ThresholdsPanel:
    """The GUI handles and actions of the editor; see :func:`attach`."""

    def __init__(
        self,
        gui: viser.GuiApi,
        get_scenario: Callable[[], Scenario],
        send: Callable[[dict[str, Any]], object],
        audit: AuditLog,
        cell: str,
        *,
        user: str = "unknown",
        no_answer: tuple[type[BaseException], ...] = (),
        who: Callable[[str], str] | None = None,
    ) -> None:
        """``who(typed name)``: the acting user's name (their credential's where one is needed;
        it raises when the acting browser may not change the cell); None: the typed name."""
        self.get_scenario, self.send, self.audit, self.cell = get_scenario, send, audit, cell
        self.who = who
        self.no_answer = no_answer
        self.folder = gui.add_folder("Thresholds", expand_by_default=True)
        with self.folder:
            self.header = gui.add_markdown("")
            self.table = gui.add_markdown("")
            self.region = gui.add_dropdown("Body region", REGIONS)
            self.contact = gui.add_dropdown("Contact", CONTACTS)
            self.shape = gui.add_dropdown("Shape", SHAPES)
            self.source = gui.add_markdown("")
            self.energy = gui.add_number("Energy [J]", 0.1, step=0.0001)
            self.user = gui.add_text("User", user)
            self.warning = gui.add_markdown("", visible=False)
            self.confirm = gui.add_checkbox("Confirm above source value", False, visible=False)
            self.apply_button = gui.add_button("Apply threshold")
            self.message = gui.add_markdown("")
            self.history = gui.add_markdown("")
        for dd in (self.region, self.contact, self.shape):
            dd.on_update(lambda _e: self.select())
        self.energy.on_update(lambda _e: self.update_warning())
        self.apply_button.on_click(on_event(self.apply))
        self.select()

    # -- state ---------------------------------------------------------------------------------
    def entry(self) -> tuple[str, str, str]:
        return str(self.region.value), str(self.contact.value), str(self.shape.value)

    def source_value(self) -> tuple[float, float]:
        """``(value in force, source value)`` of the selected entry, J."""
        sc = self.get_scenario()
        base = sc.shield.pfl.source_set()
        value, _ = effective_energy(sc, base, self.entry())
        return value, float(base.energy_J(*self.entry()))

    def select(self) -> None:
        """Show the selected entry: value in force in the number input, its source beside."""
        try:
            value, _ = self.source_value()
        except SaraError as e:
            self.show_message(f"thresholds unavailable: {e}", error=True)
            return
        self.energy.value = value  # type: ignore[misc]
        self.confirm.value = False  # type: ignore[misc]
        self.refresh()

    def refresh(self) -> None:
        """Re-read the scenario and the audit log (after edits made elsewhere too)."""
        try:
            sc = self.get_scenario()
            view = threshold_view(sc)
        except SaraError as e:
            self.show_message(f"thresholds unavailable: {e}", error=True)
            return
        row = next(
            r for r in view["entries"] if (r["region"], r["contact"], r["shape"]) == self.entry()
        )
        self.table.content = table_markdown(view["entries"])
        iso = ", ".join(f"{x['iso_region']} {x['energy_J']:.3g} J" for x in row["iso_reference"])
        mode = view["safety_mode"]
        note = "" if mode_facts(mode).contact_allowed else " (thresholds act in PFL mode)"
        self.header.content = (
            f"Scenario **{view['scenario']}**, set `{view['thresholds']}`, "
            f"safety mode **{mode}**{note}"
        )
        self.source.content = (
            f"In force: **{row['energy_J']:g} J**{' (edited)' if row['overridden'] else ''}  \n"
            f"Source: **{row['source_energy_J']:g} J**, {row['source_key']}: {row['source_text']}"
            + (f"  \nISO/TS 15066 Annex A (reference): {iso}" if iso else "")
        )
        self.update_warning()
        self.refresh_history()

    def refresh_history(self) -> None:
        try:
            rows = self.audit.entries(self.cell, AUDIT_ROWS)
        except SaraError as e:
            self.history.content = f"**⚠ audit log unavailable:** {e}"
            return
        self.history.content = audit_markdown(rows)

    def update_warning(self) -> None:
        """Show the warning and the confirmation box while the value exceeds its source."""
        try:
            _, src = self.source_value()
        except SaraError:
            return
        value = self.energy.value
        above = isinstance(value, int | float) and value > src
        self.warning.visible = self.confirm.visible = above
        if above:
            self.warning.content = (
                f"**⚠ {value:g} J exceeds the source value {src:g} J** of "
                f"{'/'.join(self.entry())}: tick the confirmation to apply it."
            )
        else:
            self.confirm.value = False  # type: ignore[misc]

    def show_message(self, text: str, error: bool = False) -> None:
        self.message.content = f"**⚠ {text}**" if error else text

    # -- action --------------------------------------------------------------------------------
    def apply(self) -> bool:
        """The "Apply threshold" button: validate, send, record; True when the worker accepted."""
        entry = self.entry()
        try:
            user = self.user.value if self.who is None else self.who(self.user.value)
            plan, _ = apply_edit(
                self.get_scenario(),
                *entry,
                self.energy.value,
                confirm=bool(self.confirm.value),
                send=self.send,
                audit=self.audit,
                cell=self.cell,
                user=user,
                via="dashboard",
                no_answer=self.no_answer,
            )
        except ConfirmationRequired as e:
            self.warning.content = f"**⚠ {e}**"
            self.warning.visible = self.confirm.visible = True
            self.show_message("Not applied: confirm the value above its source first", True)
            self.refresh_history()
            return False
        except (SaraError, ValueError) as e:
            self.show_message(f"Threshold refused: {e}", error=True)
            self.refresh_history()
            return False
        except Exception as e:  # noqa: BLE001 - a GUI callback must report, never die
            log.exception("threshold edit failed")
            self.show_message(f"Threshold edit failed: {e!r}", error=True)
            self.refresh_history()
            return False
        self.confirm.value = False  # type: ignore[misc]
        self.refresh()
        self.show_message(
            f"{'/'.join(entry)}: {plan.old_energy_J:g} → {plan.new_energy_J:g} J applied"
            + (" (override removed: back at the source value)" if plan.removes_override else "")
        )
        return True


def attach(
    gui: viser.GuiApi,
    get_scenario: Callable[[], Scenario],
    send: Callable[[dict[str, Any]], object],
    audit: AuditLog,
    cell: str,
    **kwargs: Any,
) -> ThresholdsPanel:
    """Add the threshold editor to ``gui`` (e.g. inside a tab: ``with tab: attach(...)``)."""
    return ThresholdsPanel(gui, get_scenario, send, audit, cell, **kwargs)


def table_markdown(entries: list[dict[str, Any]]) -> str:
    """The thresholds in force (J) as one table: a row per body region and contact type, a
    column per contact shape; edited values in bold with their source value beside."""
    cell = {(e["region"], e["contact"], e["shape"]): e for e in entries}
    lines = ["| region, contact | " + " | ".join(SHAPES) + " |",
             "|---|" + "---|" * len(SHAPES)]  # fmt: skip
    for region in REGIONS:
        for contact in CONTACTS:
            vals = []
            for shape in SHAPES:
                e = cell.get((region, contact, shape))
                if e is None:
                    vals.append("n/a")
                elif e["overridden"]:
                    vals.append(f"**{e['energy_J']:g}** ({e['source_energy_J']:g})")
                else:
                    vals.append(f"{e['energy_J']:g}")
            lines.append(f"| {region}, {contact} | " + " | ".join(vals) + " |")
    return "Energies in force, J (edited: **bold**, source value in brackets)\n\n" + "\n".join(
        lines
    )
