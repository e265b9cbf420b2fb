"""What a client's scenario edit may not do on its own (``sara_app.ops.client_edits``): refer to
a file of the server's (robot URDF, recording, parameter or threshold set by path) that the cell
does not already use, or raise a contact-energy limit in force; the API routes and the
dashboard's edit path refuse both (hostile-user probe of 2026-11-30)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from sara_app.ops.client_edits import (
    EditRefusedError,
    check_client_edit,
    check_no_raise,
    file_references,
    raised_energies,
)
from sara_app.safety.thresholds import load_thresholds
from sara_app.scenario import load_scenario, parse_scenario

BASE = load_scenario("punches").model_dump(mode="json")
HEAD = {"region": "head", "contact": "unconstrained", "shape": "blunt"}
SOURCE_HEAD_J = load_thresholds().energy_J("head", "unconstrained", "blunt")


def _with(**paths: object) -> dict:
    data = copy.deepcopy(BASE)
    for dotted, value in paths.items():
        *parents, last = dotted.split("__")
        node = data
        for p in parents:
            node = node[int(p)] if isinstance(node, list) else node[p]
        node[last] = value
    return data


def test_names_are_not_file_references() -> None:
    assert file_references(BASE) == {}
    named = _with(human_params="fast", robot__name="ur10e")
    named["humans"] = [{"id": "w", "type": "recording", "recording": "CollaborativeHammering/0"}]
    assert file_references(named) == {}
    assert file_references("not a scenario") == {} and file_references(None) == {}


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("shield__pfl__thresholds", "/etc/thresholds.json"),
        ("shield__pfl__thresholds", "thresholds_mine"),  # not shipped: read as a path
        ("human_params", "/root/.local/share/sara_app/api_tokens.json"),
        ("human_params", "mine.json"),
        ("robot__name", "/tmp/arm.urdf"),
    ],
)
def test_paths_are_file_references(field: str, value: str) -> None:
    assert file_references(_with(**{field: value})) == {field.replace("__", "."): value}


@pytest.mark.parametrize(
    "recording", ["/tmp/x.bvh", "../secret", "a/../../b", "~/x.bvh", "walk.bvh/../x", " 02_01"]
)
def test_recordings_outside_the_data_folders_are_file_references(recording: str) -> None:
    data = copy.deepcopy(BASE)
    data["humans"] = [{"id": "w", "type": "recording", "recording": recording}]
    assert file_references(data) == {"humans.0.recording": recording}


def test_a_recording_name_that_is_a_file_beside_the_server_is_a_path(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """find_recording takes a file of that name in the working directory first."""
    (tmp_path / "02_01").write_text("secret")
    monkeypatch.chdir(tmp_path)
    data = copy.deepcopy(BASE)
    data["humans"] = [{"id": "w", "type": "recording", "recording": "02_01"}]
    assert file_references(data) == {"humans.0.recording": "02_01"}


def test_a_path_the_cell_already_uses_is_kept_a_new_one_refused() -> None:
    running = _with(human_params="/srv/cell/fitted.json")
    check_client_edit(running, _with(human_params="/srv/cell/fitted.json", name="x"))
    with pytest.raises(EditRefusedError, match="human_params .* refers to a file") as e:
        check_client_edit(running, _with(human_params="/srv/other.json"))
    assert "bench_work" in str(e.value) and "thresholds_thumm2024" in str(e.value)
    with pytest.raises(EditRefusedError, match="shield.pfl.thresholds"):
        check_client_edit(None, _with(shield__pfl__thresholds="/tmp/t.json"))


def _overrides(*entries: tuple[dict, float]) -> dict:
    data = copy.deepcopy(BASE)
    data["shield"]["pfl"]["overrides"] = [{**e, "energy_J": j} for e, j in entries]
    return data


def test_raised_energies_against_the_limits_in_force() -> None:
    base = parse_scenario(BASE)
    up = parse_scenario(_overrides((HEAD, 9.5)))
    assert raised_energies(base, up) == [f"head/unconstrained/blunt {SOURCE_HEAD_J:g} -> 9.5 J"]
    down = parse_scenario(_overrides((HEAD, 0.05)))
    assert raised_energies(base, down) == []  # a tightening
    assert raised_energies(down, base) == [f"head/unconstrained/blunt 0.05 -> {SOURCE_HEAD_J:g} J"]
    assert raised_energies(None, up) and not raised_energies(None, down)
    with pytest.raises(EditRefusedError, match="threshold editor \\(the tab\\)"):
        check_no_raise(down, base, thresholds_path="the tab")
    check_no_raise(base, down, thresholds_path="the tab")


def test_validation_errors_of_a_file_do_not_repeat_its_content(tmp_path: Path) -> None:
    """A file read on the server's side that is not a valid set: the error names the fields,
    never the values (the probe got the API's tokens back this way)."""
    from sara_app.errors import ParameterError
    from sara_app.human.params import load_param_set

    secret = tmp_path / "tokens.json"
    secret.write_text(json.dumps({"tok-4f1c9e": "operator"}))
    with pytest.raises(ParameterError) as e:
        load_param_set(secret)
    assert "tok-4f1c9e" not in str(e.value) and "operator" not in str(e.value)
    with pytest.raises(ParameterError) as e:
        load_thresholds(secret)
    assert "tok-4f1c9e" not in str(e.value) and "operator" not in str(e.value)
