"""safety.settings.mode_facts, the one table outside the shields that tells the modes apart, agrees
with what each mode's shield produces in a real closed loop."""

from __future__ import annotations

import pytest

from sara_app.errors import UnknownNameError
from sara_app.safety.settings import SAFETY_MODES, mode_facts, models_of_mode
from sara_app.scenario import load_scenario
from sara_app.sim.compare import with_mode
from sara_app.sim.simulator import Simulation


@pytest.mark.parametrize("mode", SAFETY_MODES)
def test_the_facts_match_what_the_shield_produces(mode: str) -> None:
    facts = mode_facts(mode)
    sim = Simulation(with_mode(load_scenario("close_worker"), mode))
    seen = {"scale": False, "index": False, "energies": False}
    for _ in range(3000):  # 6 s: the worker comes close enough to slow the robot down
        sim.step()
        res = sim.last
        assert res is not None and res.safety_mode == mode
        seen["scale"] |= res.speed_scale is not None and res.speed_scale < 1.0
        seen["index"] |= res.jssa is not None
        seen["energies"] |= res.pfl is not None
    assert seen["index"] == facts.safety_index
    assert seen["energies"] == facts.contact_allowed
    assert seen["scale"] == facts.scales_speed
    assert ("arm" in models_of_mode(mode, ["pos", "arm"])) == facts.arm_model


def test_an_unknown_mode_is_refused_with_the_choices() -> None:
    with pytest.raises(UnknownNameError, match="ssm"):
        mode_facts("iso")
