"""Key expressions: build/parse round trips, name validation, wildcards match their keys."""

from __future__ import annotations

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from sara_app.bus import keys
from sara_app.errors import InputError, UnknownNameError

names = st.from_regex(keys.NAME_PATTERN, fullmatch=True)


WITH_ID = ("skeleton", "tracker_frame")


def _all_keys(cell: str, human: str) -> dict[str, str]:
    return {k: keys.key(k, cell, human if k in WITH_ID else None) for k in keys.KINDS}


def test_documented_layout() -> None:
    assert keys.skeleton_key("c1", "h7") == "sara/c1/human/h7/skeleton"
    assert keys.robot_state_key("c1") == "sara/c1/robot/state"
    assert keys.robot_command_key("c1") == "sara/c1/robot/command"
    assert keys.verdict_key("c1") == "sara/c1/verdict"
    assert keys.occupancy_key("c1") == "sara/c1/occupancy"
    assert keys.params_key("c1") == "sara/c1/params"
    assert keys.params_ack_key("c1") == "sara/c1/params/ack"
    assert keys.status_key("c1") == "sara/c1/status"
    assert keys.tracker_frame_key("c1", "cam2") == "sara/c1/tracker/cam2/frame"
    assert keys.retire_key("c1") == "sara/c1/retire"


@given(cell=names, human=names)
def test_round_trip_and_wildcards(cell: str, human: str) -> None:
    built = _all_keys(cell, human)
    assert len(set(built.values())) == len(keys.KINDS)
    cell_wild = zenoh.KeyExpr(keys.cell_keys(cell))
    for kind, k in built.items():
        parsed = keys.parse_key(k)
        assert parsed == (cell, kind, human if kind in WITH_ID else None)
        zk = zenoh.KeyExpr(k)  # zenoh accepts every key we build
        assert cell_wild.intersects(zk)
        assert zenoh.KeyExpr(keys.skeleton_keys(cell)).intersects(zk) == (kind == "skeleton")
        assert zenoh.KeyExpr(keys.all_status_keys()).intersects(zk) == (kind == "status")
        frames = zenoh.KeyExpr(keys.tracker_frame_keys(cell))
        assert frames.intersects(zk) == (kind == "tracker_frame")


@pytest.mark.parametrize(
    "bad", ["", "a/b", "a*", "$x", "**", "a b", "é", "x" * 65, "a?", "a#b", None, 3]
)
def test_bad_names_are_refused(bad: object) -> None:
    with pytest.raises(InputError, match="not a valid name"):
        keys.check_name("cell", bad)
    with pytest.raises(InputError):
        keys.verdict_key(bad)  # type: ignore[arg-type]
    with pytest.raises(InputError):
        keys.skeleton_key("c1", bad)  # type: ignore[arg-type]


def test_key_arguments() -> None:
    with pytest.raises(UnknownNameError, match="valid choices"):
        keys.key("skeletons", "c1", "h1")
    with pytest.raises(InputError, match="takes no id"):
        keys.key("verdict", "c1", "h1")
    with pytest.raises(InputError):
        keys.key("skeleton", "c1")


@pytest.mark.parametrize(
    "bad",
    [
        "sara",
        "sara/c1",
        "other/c1/verdict",
        "sara/c1/verdicts",
        "sara/c1/human/h1",
        "sara/c1/human/h1/skeleton/x",
        "sara/c*/verdict",
        "sara/c1/human/*/skeleton",
        "sara/c1/params/ack/x",
        "sara//verdict",
    ],
)
def test_parse_refuses_foreign_keys(bad: str) -> None:
    with pytest.raises(InputError):
        keys.parse_key(bad)
