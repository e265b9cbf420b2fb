"""What a human set is sound on, in words (sara_app.human.sound_record) and as the dashboard
shows it (sara_app.dashboard.human_set_text): its counts against the set's own record recomputed
here from the raw JSON (the oracle), for every shipped set; records it cannot read are said to be
unreadable, never guessed at and never an exception; text from the set cannot break the table or
inject markup."""

from __future__ import annotations

import json
import re

import pytest

from sara_app.dashboard.human_set_text import human_set_markdown
from sara_app.human.params import ParamSet, available_param_sets, load_param_set
from sara_app.human.sound_record import TEXT_LIMIT


def _rows(md: str) -> dict[str, str]:
    """The table's rows as label -> text; every row must have exactly two cells."""
    out = {}
    for line in md.splitlines():
        if line.startswith("|") and not line.startswith("|---") and "What |" not in line:
            cells = re.split(r"(?<!\\)\|", line)[1:-1]
            assert len(cells) == 2, line
            out[cells[0].strip()] = cells[1].strip()
    return out


def _with_record(record: dict[str, str], **fields: str) -> ParamSet:
    return load_param_set("bench_work").model_copy(update={"sound_for": record, **fields})


@pytest.mark.parametrize("name", available_param_sets())
def test_every_shipped_set_is_summarised_with_its_own_counts(name: str) -> None:
    ps = load_param_set(name)
    md = human_set_markdown(ps)
    assert md.startswith(f"**{ps.name}**")
    rows = _rows(md)
    record = ps.sound_for
    assert len(rows) == len([k for k in record if k != "horizon_s"])
    fitted = record.get("misses_per_recording")
    if fitted is not None:
        table = json.loads(fitted)
        assert rows["Fitted to"].startswith(f"{len(table)} recordings (")
        if all("effective" in v for v in table.values()):
            eff = sum(v["effective"] for v in table.values())
            assert f"the effective set misses {eff} future positions" in rows["Fitted to"]
        else:  # an older record without the effective set's column claims nothing of it
            assert "effective" not in rows["Fitted to"]
    loo = record.get("leave_one_out")
    if loo is not None:
        table = json.loads(loo)
        whole = sum(v["share"] >= 1.0 for v in table.values())
        misses = sum(v["misses"] for v in table.values())
        unflagged = sum(v["unflagged"] for v in table.values())
        label = "Each recording left out of the fit"
        if "margin_v_a_arm" in record:
            label += ", fitted without the margin this gave the set"
        text = rows[label]
        assert text.startswith(f"{whole} of {len(table)} contained whole")
        assert f"{misses:,} future positions".replace(",", " ") in text
        assert f"{unflagged:,} of them unflagged".replace(",", " ") in text
    for label, text in rows.items():
        assert len(text) <= TEXT_LIMIT or label == "Fitted to", (label, text)
        assert '{"' not in text, (label, text)  # a table is counted, never dumped


def test_pairs_per_recording_and_horizon_are_summed_per_horizon() -> None:
    record = {
        "displacement_left_out_misses_unflagged": json.dumps(
            {"a": {"0.1s": [3, 1], "0.5s": [10, 4]}, "b": {"0.1s": [2, 0], "0.5s": [5, 5]}}
        ),
        "legs_unmeasured_left_out_misses_unflagged_0_5s": json.dumps({"a": [7, 7], "b": [0, 0]}),
    }
    rows = _rows(human_set_markdown(_with_record(record)))
    disp = rows["Displacement bound, each left out"]
    assert disp == "2 recordings; 0.1s: 5 misses, 1 unflagged; 0.5s: 15 misses, 9 unflagged"
    legs = next(v for k, v in rows.items() if k.startswith("Unmeasured legs"))
    assert legs == "2 recordings; 7 misses, 7 unflagged"


@pytest.mark.parametrize(
    "key, bad",
    [(k, b) for k in ("misses_per_recording", "leave_one_out", "some_table")
     for b in ("{", "{not json", '{"a": {"share": "x", "effective": "y"}}', '{"a": 3}')]
    + [("leave_one_out", '{"a": {"misses": 1}}'), ("leave_one_out", "[1, 2]"),
       ("misses_per_recording", "[1, 2]"), ("some_table", '{"a": [1]}')],
)  # fmt: skip
def test_a_record_it_cannot_read_is_said_to_be_one(key: str, bad: str) -> None:
    md = human_set_markdown(_with_record({key: bad}))
    (text,) = _rows(md).values()
    assert text == f"a table of {len(bad)} characters (in the set's file)", text


def test_a_set_that_records_nothing_claims_nothing() -> None:
    md = human_set_markdown(_with_record({}))
    assert "sound on no recording known" in md and "|" not in md
    assert human_set_markdown(None, "no scenario yet") == "*No human set to show: no scenario yet.*"


def test_text_from_the_set_cannot_break_the_table_or_add_markup() -> None:
    record = {"note": "a | b <script>alert(1)</script>", "long": "x" * (TEXT_LIMIT + 50)}
    md = human_set_markdown(_with_record(record, name="n|<b>", description="d <img src=x>"))
    assert "<script>" not in md and "<img" not in md and "<b>" not in md
    rows = _rows(md)  # two cells per row: the pipe is escaped
    assert rows["Note"] == "a \\| b &lt;script&gt;alert(1)&lt;/script&gt;"
    assert rows["Long"] == "x" * (TEXT_LIMIT - 3) + "..."
    braces = human_set_markdown(_with_record({}, description='{"a": 1}'))
    assert '{"a": 1}' in braces  # a description is text, whatever it starts with
