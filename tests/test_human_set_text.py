"""What the dashboard says the human set in force is sound on (sara_app.dashboard.human_set_text):
the set's name and description above its record's summary (sara_app.human.sound_record) as a
two-column table; nothing claimed for a set that records nothing; text from the set cannot break
the table or inject markup."""

from __future__ import annotations

import re

import pytest

from sara_app.dashboard.human_set_text import human_set_markdown
from sara_app.human.params import ParamSet, available_param_sets, load_param_set
from sara_app.human.sound_record import TEXT_LIMIT, summary


def _rows(md: str) -> list[tuple[str, str]]:
    """The table's rows as (label, text); every row must have exactly two cells."""
    out = []
    for line in md.splitlines():
        if line.startswith("|") and not line.startswith("|---") and "What |" not in line:
            cells = re.split(r"(?<!\\)\|", line)[1:-1]
            assert len(cells) == 2, line
            out.append((cells[0].strip(), cells[1].strip()))
    return out


def _with_record(record: dict[str, str], **fields: str) -> ParamSet:
    return load_param_set("bench_work").model_copy(update={"sound_for": record, **fields})


@pytest.mark.parametrize("name", available_param_sets())
def test_every_shipped_set_shows_its_summary_row_by_row(name: str) -> None:
    ps = load_param_set(name)
    md = human_set_markdown(ps)
    assert md.startswith(f"**{ps.name}**")
    assert _rows(md) == [(w.replace("&", "&amp;"), t.replace("&", "&amp;"))
                         for w, t in summary(ps.sound_for)]  # fmt: skip


def test_a_set_that_records_nothing_claims_nothing() -> None:
    md = human_set_markdown(_with_record({}))
    assert "sound on no recording known" in md and "|" not in md
    assert human_set_markdown(None, "no scenario yet") == "*No human set to show: no scenario yet.*"


def test_text_from_the_set_cannot_break_the_table_or_add_markup() -> None:
    record = {"note": "a | b <script>alert(1)</script>", "long": "x" * (TEXT_LIMIT + 50)}
    md = human_set_markdown(_with_record(record, name="n|<b>", description="d <img src=x>"))
    assert "<script>" not in md and "<img" not in md and "<b>" not in md
    rows = dict(_rows(md))  # two cells per row: the pipe is escaped
    assert rows["Note"] == "a \\| b &lt;script&gt;alert(1)&lt;/script&gt;"
    assert rows["Long"] == "x" * (TEXT_LIMIT - 3) + "..."
    braces = human_set_markdown(_with_record({}, description='{"a": 1}'))
    assert '{"a": 1}' in braces  # a description is text, whatever it starts with
