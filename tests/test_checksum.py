"""The configuration checksum: the same configuration gives the same value (also after a JSON
round trip), and any change of the scenario, of the parameter or threshold set's contents, or
of the code gives another."""

from __future__ import annotations

from pathlib import Path

import pytest

from sara_app.cell import checksum
from sara_app.cell.checksum import config_checksum
from sara_app.human.params import load_param_set
from sara_app.scenario import load_scenario, parse_scenario


def _edited(data: dict, path: str, value: object) -> dict:
    node = data
    keys = path.split(".")
    for k in keys[:-1]:
        node = node[int(k)] if isinstance(node, list) else node[k]
    node[keys[-1]] = value
    return data


def test_same_configuration_same_checksum_any_edit_another() -> None:
    sc = load_scenario("close_worker")
    base = config_checksum(sc)
    assert len(base) == 64 and int(base, 16) >= 0
    again = parse_scenario(sc.model_dump(mode="json"), "round trip")
    assert config_checksum(again) == base
    named = load_param_set("schepp2022_table1").model_dump(mode="json")
    edits = {
        "task.cycles": 2,
        "humans.0.position_m": [0.95, 0.0],
        "shield.mode": "ssm",
        "limits.velocity": 0.9,
        "human_params": "work",
        # the same set by content, one bound changed: a content edit under the same name
        "human_params.joints": None,
        "shield.pfl.overrides": [
            {"region": "hand", "contact": "constrained", "shape": "blunt", "energy_J": 0.1}
        ],  # fmt: skip
    }
    seen = {base}
    for path, value in edits.items():
        data = sc.model_dump(mode="json")
        if path == "human_params.joints":
            data["human_params"] = {**named, "joints": {**named["joints"],
                                                        "head": {"v_max_mps": 2.1,
                                                                 "a_max_mps2": 25.0}}}  # fmt: skip
        else:
            data = _edited(data, path, value)
        got = config_checksum(parse_scenario(data, path))
        assert got not in seen, path
        seen.add(got)


def test_the_code_is_part_of_the_checksum(monkeypatch: pytest.MonkeyPatch) -> None:
    sc = load_scenario("close_worker")
    base = config_checksum(sc)
    digest = checksum.code_digest()
    assert len(digest) == 64
    monkeypatch.setattr(checksum, "code_digest", lambda: "0" * 64)
    assert config_checksum(sc) != base
    monkeypatch.setattr(checksum, "__version__", "9.9.9")
    assert config_checksum(sc) != base


def test_the_code_digest_covers_every_folder_of_the_package() -> None:
    import sara_app

    root = Path(sara_app.__file__).resolve().parent
    assert checksum.PACKAGE_DIR == root
    folders = {p.parent.relative_to(root).parts[:1] for p in root.rglob("*.py")}
    assert {("safety",), ("human",), ("robot",), ("runtime",), ()} <= folders
