"""Which scenario edits loosen what the verdict assumes (``sara_app.ops.loosening``)."""

from __future__ import annotations

import copy
from collections.abc import Callable, Iterator
from typing import Any

import pytest
from pydantic import ValidationError

from sara_app.errors import SaraError
from sara_app.human.params import load_param_set
from sara_app.ops.loosening import (
    FREE,
    HIGHER_LOOSENS,
    LOWER_LOOSENS,
    LooseningRefusedError,
    check_loosening,
    loosenings,
)
from sara_app.safety.topology import ROBOT_UNCLAMPABLE_PAIRS
from sara_app.scenario import Scenario, load_scenario, parse_scenario


@pytest.fixture(scope="module")
def base() -> Scenario:
    return load_scenario("punches")  # a bench cell: a box, full sections


def _edited(sc: Scenario, change: Callable[[dict[str, Any]], object]) -> Scenario:
    data = copy.deepcopy(sc.model_dump(mode="json"))
    change(data)
    return parse_scenario(data, "test edit")


def _set(path: str, value: Any) -> Callable[[dict[str, Any]], None]:
    def change(data: dict[str, Any]) -> None:
        *head, last = path.split(".")
        for k in head:
            data = data[k]
        data[last] = value

    return change


def _get(sc: Scenario, path: str) -> Any:
    data: Any = sc.model_dump(mode="json")
    for k in path.split("."):
        data = data[k]
    return data


def test_the_same_scenario_loosens_nothing(base: Scenario) -> None:
    assert loosenings(base, base) == []
    assert loosenings(base, _edited(base, lambda d: None)) == []


@pytest.mark.parametrize("path", sorted(HIGHER_LOOSENS) + sorted(LOWER_LOOSENS))
def test_a_directed_field_loosens_one_way_only(base: Scenario, path: str) -> None:
    if not _get(base, path):  # a zero margin cannot shrink: start from one
        base = _edited(base, _set(path, 0.05))
    value = _get(base, path)
    higher = _edited(base, _set(path, value * 1.5))
    lower = _edited(base, _set(path, value / 2))
    looser, tighter = (higher, lower) if path in HIGHER_LOOSENS else (lower, higher)
    found = loosenings(base, looser)
    assert len(found) == 1 and found[0].startswith(f"{path}: ")
    assert loosenings(base, tighter) == []


def _numeric_leaves(data: Any, path: str = "") -> Iterator[tuple[str, float]]:
    if isinstance(data, dict):
        for k, v in data.items():
            yield from _numeric_leaves(v, f"{path}.{k}" if path else k)
    elif isinstance(data, int | float) and not isinstance(data, bool):
        yield path, float(data)


def test_every_other_field_loosens_whichever_way_it_changes(base: Scenario) -> None:
    """CONSERVATIVE default: a numeric field that is neither free nor given a direction is a
    loosening when it changes up and when it changes down (robot pose, human model, PFL, ...)."""
    directed = set(HIGHER_LOOSENS) | set(LOWER_LOOSENS)
    assert isinstance(base.human_params, str)
    named = load_param_set(base.human_params).model_dump(mode="json")
    inline = _edited(base, _set("human_params", named))  # its bounds as fields
    checked = 0
    for path, value in _numeric_leaves(inline.model_dump(mode="json")):
        if path in directed or any(path == f or path.startswith(f + ".") for f in FREE):
            continue
        step = max(abs(value) * 0.1, 0.01)
        for new in (value + step, value - step):
            try:
                edited = _edited(inline, _set(path, new))
            except (ValidationError, SaraError):
                continue  # out of the field's range: not a scenario
            assert any(x.startswith(path) for x in loosenings(inline, edited)), (path, new)
            checked += 1
    assert checked >= 20  # the human model's bounds, the robot's pose, the boxes, ...


def test_free_fields_are_no_loosening(base: Scenario) -> None:
    for change in (
        _set("description", "another"),
        _set("shield.mode", "pfl"),
        _set("shield.ssm.cut", 0.5),
        _set("limits.velocity", 0.5),
        _set("sim.seed", 7),
        _set("inputs.max_people", 3),
        _set("humans", []),
    ):
        assert loosenings(base, _edited(base, change)) == []


def test_boxes_removed_or_moved_loosen_added_ones_do_not(base: Scenario) -> None:
    box = base.environment[0].model_dump(mode="json")
    gone = loosenings(base, _edited(base, _set("environment", [])))
    assert len(gone) == 1 and f"{box['name']!r} removed" in gone[0]
    moved = {**box, "center_m": [box["center_m"][0] + 0.2, *box["center_m"][1:]]}
    found = loosenings(base, _edited(base, _set("environment", [moved])))
    assert len(found) == 1 and "center_m" in found[0]
    extra = {**box, "name": "shelf", "center_m": [2.0, 2.0, 0.5]}
    assert loosenings(base, _edited(base, _set("environment", [box, extra]))) == []


def test_models_added_loosen_removed_ones_tighten(base: Scenario) -> None:
    models = list(base.shield.models)
    fewer = _edited(base, _set("shield.models", models[:1]))
    assert loosenings(base, fewer) == []
    found = loosenings(fewer, base)  # every model added back: one more chance to clear each
    assert len(found) == len(models) - 1 and all("added" in x for x in found)


def test_trackers_removed_loosen(base: Scenario) -> None:
    two = _edited(base, _set("inputs.trackers", ["main", "second"]))
    assert loosenings(base, two) == []
    found = loosenings(two, base)
    assert found == ["inputs.trackers: 'second' removed (the robot no longer waits for that "
                     "tracker's frames)"]  # fmt: skip


def test_unclampable_pairs_compare_with_the_robots_declaration(base: Scenario) -> None:
    declared = [list(p) for p in ROBOT_UNCLAMPABLE_PAIRS[base.robot.name]]
    assert declared, "the Panda declares pairs"
    assert loosenings(base, _edited(base, _set("shield.pfl.unclampable_pairs", declared))) == []
    assert loosenings(base, _edited(base, _set("shield.pfl.unclampable_pairs", declared[:1]))) == []
    links = base.robot.load().link_names
    new = [links[0], links[-1]]
    found = loosenings(base, _edited(base, _set("shield.pfl.unclampable_pairs", [*declared, new])))
    assert len(found) == 1 and "/".join(sorted(new)) in found[0]


def test_another_human_model_or_a_moved_robot_loosens(base: Scenario) -> None:
    other = "bench_work" if base.human_params != "bench_work" else "fast"
    assert loosenings(base, _edited(base, _set("human_params", other)))
    found = loosenings(base, _edited(base, _set("robot.base_xyz_m", [70.0, 0.0, 0.0])))
    assert len(found) == 1 and found[0].startswith("robot.base_xyz_m")
    off = _edited(base, _set("inputs.gate.stale_tracker", False))
    assert loosenings(base, off) and loosenings(off, base) == []


def test_without_the_scenario_in_force_every_edit_needs_a_confirmation(base: Scenario) -> None:
    assert len(loosenings(None, base)) == 1


def test_check_refuses_without_confirmation_and_says_how(base: Scenario) -> None:
    looser = _edited(base, _set("shield.skeleton_timeout_s", 1.0))
    with pytest.raises(LooseningRefusedError, match="skeleton_timeout_s: 0.2 -> 1.0") as e:
        check_loosening(base, looser, confirm=False, how_to_confirm="tick the box")
    assert "tick the box" in str(e.value) and len(e.value.changes) == 1
    assert check_loosening(base, looser, confirm=True, how_to_confirm="") == e.value.changes
    assert check_loosening(base, base, confirm=False, how_to_confirm="") == []


def test_trusting_stated_velocities_is_a_loosening_and_distrusting_them_is_not(
    base: Scenario,
) -> None:
    trusting = _edited(base, _set("inputs.trust_stated_velocities", True))
    found = loosenings(base, trusting)
    assert len(found) == 1 and found[0].startswith("inputs.trust_stated_velocities: False -> True")
    assert loosenings(trusting, base) == []
