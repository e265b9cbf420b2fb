"""A human set's record of what it is sound on, in words (sara_app.human.sound_record): its counts
against the set's own record recomputed here from the raw JSON (the oracle), for every shipped
set; tables of misses per recording and horizon summed per horizon; records it cannot read are
said to be unreadable, never guessed at and never an exception."""

from __future__ import annotations

import json

import pytest

from sara_app.human.params import available_param_sets, load_param_set
from sara_app.human.sound_record import TEXT_LIMIT, summary


@pytest.mark.parametrize("name", available_param_sets())
def test_every_shipped_set_is_summarised_with_its_own_counts(name: str) -> None:
    record = load_param_set(name).sound_for
    rows = dict(summary(record))
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
    margin = [k for k in record if k.startswith("margin_")]
    assert len(margin) <= 1, margin  # applied or declined, never both
    if "margin_declined_v_a_arm" in record:
        said = rows["Margin it would need, not applied (speeds, accelerations, arm)"]
        assert said == record["margin_declined_v_a_arm"]
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
    rows = dict(summary(record))
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
    ((_, text),) = summary({key: bad})
    assert text == f"a table of {len(bad)} characters (in the set's file)", text


def test_free_text_is_given_as_written_shortened_and_the_horizon_goes_with_the_counts() -> None:
    rows = summary({"note": "as written", "long": "x" * (TEXT_LIMIT + 50), "horizon_s": "0.5"})
    assert rows == [("Note", "as written"), ("Long", "x" * (TEXT_LIMIT - 3) + "...")]
    assert summary({}) == []
