"""The verdict in words (sara_app.bus.verdict_words): each state's sentence says what the robot
does and why, from the verdict's own fields; and the shield names the body parts it could not
clear (Shield.blocking) exactly where its per-part result says so."""

from __future__ import annotations

import numpy as np

from sara_app.bus.messages import VerdictMsg
from sara_app.bus.verdict_words import COLOURS, part_words, verdict_words
from sara_app.scenario import load_scenario
from sara_app.sim.simulator import Simulation


def _v(**kw: object) -> VerdictMsg:
    base = {"seq": 1, "stamp_s": 1.0, "cell": "c", "safety_mode": "ssm", "mode": "intended",
            "cycle_time_us": 80.0}  # fmt: skip
    return VerdictMsg(**{**base, **kw})  # type: ignore[arg-type]


def test_each_state_in_words() -> None:
    w = verdict_words(_v(min_distance_m=1.234))
    assert (w.state, w.sentence) == ("moving", "Moving on its verified path (SSM), 1.23 m from "
                                     "the robot")  # fmt: skip
    w = verdict_words(_v(intervened=True, speed_scale=0.4, blocking=["p1 r_hand"],
                         min_distance_m=0.61))  # fmt: skip
    assert w.state == "slowed" and "40 % of its speed by SSM: p1's right hand, 0.61 m" in w.sentence
    w = verdict_words(_v(mode="failsafe", blocking=["p2 head", "p2 torso"], min_distance_m=0.2))
    assert w.state == "braking"
    assert w.sentence == ("Braking along the verified stop (SSM): p2's head (and 1 more), 0.20 m "
                          "from the robot")  # fmt: skip
    w = verdict_words(_v(mode="fault", faults=["p1: no skeleton for 0.31 s"]), fault_for_s=12.4)
    assert w.state == "fault" and w.sentence.startswith("Fault for 12 s: p1: no skeleton")
    assert "check that the tracker runs" in w.sentence
    assert verdict_words(_v(), online=False).state == "offline"
    assert verdict_words(None).state == "offline"
    assert verdict_words(_v(mode="rest")).sentence == "At rest"
    assert {verdict_words(_v(mode=m)).colour for m in ("intended", "failsafe", "fault")} <= set(
        COLOURS.values()
    )
    w = verdict_words(_v(mode="failsafe", min_distance_m=-0.05))
    assert w.sentence.endswith("a person, touching the robot's capsules (0.05 m deep)")
    assert part_words([]) == "a person" and part_words(["p1 l_shin"]) == "p1's left shin"
    w = verdict_words(_v(intervened=True, speed_scale=0.1, skeleton_age_s={"p7": 0.01}))
    assert "by SSM: p7 nearby" in w.sentence  # no part named: the one person in view


def test_the_shield_names_the_parts_it_could_not_clear() -> None:
    """standing_beside_path in SSM: while the robot slows or brakes, the named parts are those whose
    per-part result is not clear on every interval (at most 8), each '<person> <part>'."""
    sim = Simulation(load_scenario("standing_beside_path"))
    named = 0
    for _ in range(2500):
        sim.step()
        res = sim.last
        assert res is not None
        got = sim.shield.blocking(res)
        if res.ssm is None or not res.human_ids:
            assert got == []
            continue
        blocked = ~res.ssm.parts_clear.all(axis=1)
        parts = sim.shield.reach.skeleton.parts
        want = [f"{res.human_ids[h]} {parts[p]}" for h, p in zip(*np.nonzero(blocked))]
        assert got == want[:8]
        named += bool(got)
    assert named > 0  # the person did keep the check from clearing now and then
