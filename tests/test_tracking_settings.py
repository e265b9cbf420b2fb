"""What a scenario says about tracking (``sara_app.human.tracking_settings``): the settings refuse
what the gate cannot use, naming the valid choices; and reading a scenario loads no compiled
kernel, so the processes that never track a person (the reference controller, the router)
start without loading the shield's kernels (about a second of every start before)."""

from __future__ import annotations

import subprocess
import sys

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


@pytest.mark.parametrize(
    "module", ["sara_app.scenario", "sara_app.peers.controller", "sara_app.bus.router"]
)
def test_reading_a_scenario_loads_no_compiled_kernel(module: str) -> None:
    code = (
        f"import sys, {module}\n"
        "from sara_app.scenario import load_scenario\n"
        "load_scenario('close_worker')\n"
        "print(sorted(m for m in sys.modules if m.endswith('kernels')))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
