"""What a scenario says about tracking (``sara_app.human.tracking_settings``): the settings refuse
what the gate cannot use, naming the valid choices. (That reading a scenario loads no compiled
kernel: ``tests/test_process_starts.py``.)"""

from __future__ import annotations

import pytest

from sara_app.errors import ParameterError
from sara_app.human.tracking_settings import (
    BONES,
    DEFAULT_INTAKE,
    STALE_AFTER_S,
    GateSettings,
    IntakeSettings,
)


def test_a_known_bone_must_be_a_gate_bone_of_a_plausible_length() -> None:
    assert GateSettings(known_bones_m=(("l_elbow", "l_wrist", 0.27),)).known_bones_m
    with pytest.raises(ParameterError, match="l_elbow-l_wrist"):
        GateSettings(known_bones_m=(("l_wrist", "head", 0.3),))
    with pytest.raises(ParameterError, match="0 < length < 2 m"):
        GateSettings(known_bones_m=((*BONES[0], 2.5),))
    for bad in ({"bone_tol_m": -0.1}, {"learn_frames": 0}, {"max_hold_s": 0.0}):
        with pytest.raises(ParameterError, match="expected"):
            GateSettings(**bad)  # type: ignore[arg-type]


def test_the_default_intake_is_the_settings_of_a_silent_scenario() -> None:
    assert DEFAULT_INTAKE == IntakeSettings() and DEFAULT_INTAKE.gate == GateSettings()
    assert DEFAULT_INTAKE.stale_after_s == STALE_AFTER_S
