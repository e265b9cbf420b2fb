"""Threshold sets: Thumm et al. 2024 Table I fidelity, sources, validation by name, ISO
reference."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sara_app.errors import ParameterError, UnknownNameError
from sara_app.human.skeleton import skeleton
from sara_app.safety.thresholds import (
    BODY_PART_REGION,
    PARAM_DIR,
    diameters_m,
    load_thresholds,
    threshold_arrays,
)

# Thumm et al. 2024 Table I, typed in from the paper: (constrained blunt, wedge, edge, sheet;
# unconstrained blunt, wedge, edge, sheet) in J.
TABLE_I = {
    "hand": (0.12, 0.05, 0.02, 0.11, 0.49, 2.0, 0.375, 0.9),
    "lower_arm": (0.325, 0.05, 0.02, 0.11, 1.3, 2.0, 0.375, 0.9),
    "upper_arm": (0.375, 0.05, 0.02, 0.11, 1.5, 0.5, 0.2, 0.5),
    "torso_legs": (0.4, 0.05, 0.02, 0.11, 1.6, 0.5, 0.2, 0.5),
    "head": (0.0275, 0.0275, 0.0275, 0.0275, 0.11, 0.077, 0.077, 0.077),
}
SHAPES = ("blunt", "wedge", "edge", "sheet")


def test_default_set_is_table_i_with_sources() -> None:
    ts = load_thresholds()
    for region, values in TABLE_I.items():
        for s, shape in enumerate(SHAPES):
            assert ts.energy_J(region, "constrained", shape) == values[s]
            assert ts.energy_J(region, "unconstrained", shape) == values[4 + s]
    # footnotes of Table I
    assert ts.limit("hand", "constrained", "blunt").source == "iso15066"
    assert ts.limit("hand", "constrained", "edge").source == "kirschner2024_edged"
    assert ts.limit("hand", "unconstrained", "wedge").source == "kirschner2024_unconstrained"
    assert ts.limit("head", "unconstrained", "edge").source == "duma2005_eye"
    assert ts.limit("head", "constrained", "edge").source == "iso15066"
    assert all(key in ts.sources for key in ("iso15066", "duma2005_eye"))


def test_every_skeleton_part_has_a_region_and_diameter() -> None:
    ts = load_thresholds()
    parts = skeleton("full").parts
    assert set(BODY_PART_REGION) == set(parts)
    assert BODY_PART_REGION["l_hand"] == "hand" and BODY_PART_REGION["r_shin"] == "torso_legs"
    assert BODY_PART_REGION["l_lower_arm"] == "lower_arm" and BODY_PART_REGION["head"] == "head"
    d = diameters_m(ts, parts)
    assert d.shape == (14,) and np.all(d > 0)
    # body-part names map to their region's values
    assert ts.energy_J("r_upper_arm", "unconstrained", "blunt") == 1.5


def test_arrays_blunt_by_default_and_tool_shape_per_link() -> None:
    ts = load_thresholds()
    T_free, T_clamp = threshold_arrays(ts, ["l0", "tool"], ["l_hand", "head"], {"tool": "edge"})
    assert T_free.tolist() == [[0.49, 0.11], [0.375, 0.077]]
    assert T_clamp.tolist() == [[0.12, 0.0275], [0.02, 0.0275]]
    with pytest.raises(UnknownNameError, match="'gripper'.*l0, tool"):
        threshold_arrays(ts, ["l0", "tool"], ["l_hand"], {"gripper": "edge"})
    with pytest.raises(UnknownNameError, match="'knife'"):
        threshold_arrays(ts, ["l0"], ["l_hand"], {"l0": "knife"})
    with pytest.raises(UnknownNameError, match="'left_hand'"):
        threshold_arrays(ts, ["l0"], ["left_hand"])
    with pytest.raises(UnknownNameError, match="'left_hand'"):
        diameters_m(ts, ["left_hand"])


def test_lookup_errors_name_the_bad_value() -> None:
    ts = load_thresholds()
    with pytest.raises(UnknownNameError, match="'elbow'") as e:
        ts.energy_J("elbow", "constrained", "blunt")
    choices = str(e.value).split("valid choices: ")[1].split(", ")
    assert len(choices) == len(set(choices)) and "head" in choices and "l_hand" in choices
    with pytest.raises(UnknownNameError, match="'clamped'.*constrained, unconstrained"):
        ts.energy_J("hand", "clamped", "blunt")
    with pytest.raises(UnknownNameError, match="'pointed'"):
        ts.energy_J("hand", "constrained", "pointed")
    with pytest.raises(UnknownNameError, match="no_such_set"):
        load_thresholds("no_such_set")


def _write(tmp_path: Path, data: dict) -> Path:
    p = tmp_path / "t.json"
    p.write_text(json.dumps(data))
    return p


def test_incomplete_or_unknown_entries_are_errors_naming_them(tmp_path: Path) -> None:
    base = json.loads((PARAM_DIR / "thresholds_thumm2024.json").read_text())
    d = json.loads(json.dumps(base))
    del d["table"]["head"]
    with pytest.raises(ParameterError, match="missing body region head"):
        load_thresholds(_write(tmp_path, d))
    d = json.loads(json.dumps(base))
    d["table"]["hand"]["constrained"]["spike"] = {"energy_J": 0.1, "source": "iso15066"}
    with pytest.raises(ParameterError, match="unknown shape of hand/constrained 'spike'"):
        load_thresholds(_write(tmp_path, d))
    d = json.loads(json.dumps(base))
    d["table"]["hand"]["constrained"]["edge"]["source"] = "folklore"
    with pytest.raises(ParameterError, match="'folklore'"):
        load_thresholds(_write(tmp_path, d))
    d = json.loads(json.dumps(base))
    d["table"]["hand"]["constrained"]["edge"]["energy_J"] = -0.1
    with pytest.raises(ParameterError, match="greater than 0"):
        load_thresholds(_write(tmp_path, d))
    d = json.loads(json.dumps(base))
    del d["body_part_diameters"]["diameters_m"]["l_foot"]
    with pytest.raises(ParameterError, match="missing body part l_foot"):
        load_thresholds(_write(tmp_path, d))


def test_edit_flags_values_above_the_source() -> None:
    ts = load_thresholds()
    lower, above = ts.with_energy("l_hand", "constrained", "blunt", 0.1)
    assert lower.energy_J("hand", "constrained", "blunt") == 0.1 and not above
    assert ts.energy_J("hand", "constrained", "blunt") == 0.12  # original unchanged
    _, above = ts.with_energy("hand", "constrained", "blunt", 0.2)
    assert above
    with pytest.raises(ParameterError, match="greater than 0"):
        ts.with_energy("hand", "constrained", "blunt", 0.0)


def test_iso_reference_energy_is_f_squared_over_2k() -> None:
    iso = load_thresholds().iso_ts_15066_annex_a
    assert iso is not None
    hand = iso.regions["hand"]  # 140 N, 75 N/mm
    assert hand.energy_J == pytest.approx(140.0**2 / (2 * 75e3))
    assert hand.transient_energy_J == pytest.approx((2 * 140.0) ** 2 / (2 * 75e3))
    # Table I's blunt constrained upper-arm value is the ISO quasi-static energy 150^2 / 60000
    assert iso.regions["upper_arm"].energy_J == pytest.approx(0.375)
    assert len(iso.regions) == 12
