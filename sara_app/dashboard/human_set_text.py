"""What the human set in force is sound on, in words for the dashboard's Scenario tab: the set's
name, its description and its own record (:mod:`sara_app.human.sound_record`), escaped."""

from __future__ import annotations

from sara_app.dashboard.tracking_text import md_cell
from sara_app.human.params import ParamSet
from sara_app.human.sound_record import short, summary


def human_set_markdown(ps: ParamSet | None, why_none: str = "") -> str:
    """Markdown: the set's name, its description and its record of what it is sound on;
    ``ps`` None: ``why_none`` (no set known yet, or it cannot be read)."""
    if ps is None:
        return f"*No human set to show{': ' + md_cell(why_none) if why_none else ''}.*"
    lines = [f"**{md_cell(ps.name)}**", ""]
    if ps.description:
        lines += [md_cell(short(ps.description)), ""]
    rows = summary(ps.sound_for)
    if not rows:
        lines.append("*The set records nothing it was checked on: sound on no recording known.*")
        return "\n".join(lines)
    lines += ["| What | On the recordings |", "|---|---|"]
    lines += [f"| {md_cell(what)} | {md_cell(text)} |" for what, text in rows]
    return "\n".join(lines)
