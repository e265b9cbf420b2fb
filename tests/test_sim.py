"""Closed-loop simulation (``sara_app.sim.simulator``): zero collisions while moving in every
shipped scenario and in seeded randomised adversarial episodes; the robot reaches its goal where the
person stays clear and beside the path; and the collision counter does fire when the shield is
replaced by one that always commits the intended step.

Run lengths. After the robot reaches its goal it stays at rest (the last pass is done, nothing
replans), so no collision while moving can follow: a run stops there. Scenarios whose goal comes
later than the person's motion are cut after the motion has ended (box_pick_place: motion
1.0 to 8.14 s; cmu_walk: walk 1.0 to 4.85 s); the adversarial scenario is cut at 2 s (its closest
approaches come in the first second, the 200-episode command runs the rest).
"""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.safety.ssm import SsmResult
from sara_app.scenario import load_scenario, parse_scenario, scenario_names
from sara_app.sim.episodes import run_episodes
from sara_app.sim.simulator import SimMetrics, Simulation

# scenario -> (horizon s or None for the scenario's duration, goal must be reached)
PLAN: dict[str, tuple[float | None, bool]] = {
    "empty_cell": (None, True),
    "standing_beside_path": (None, True),
    "punches": (None, True),
    "headbutt": (None, True),
    "slow_approach": (None, True),
    "box_pick_place": (8.2, False),
    "cmu_walk": (5.0, False),
    "adversarial": (2.0, False),
    "close_worker": (None, True),
    "tracking_glitches": (None, True),
    "ur10e_close_worker": (None, True),
    "bench_worker": (None, True),
    "bench_handover": (None, True),
    "bench_handover_upper": (None, True),
}
FAULTS_BY_DESIGN = {"tracking_glitches"}
"""Its spike is a fault until the person has kept within the bounds for recover_s
(tests/test_sim_tracking.py counts every flag)."""


def run_until_goal(sim: Simulation, horizon_s: float) -> SimMetrics:
    n = int(round(horizon_s / sim.dt))
    for _ in range(n):
        sim.step()
        if sim.time_to_goal_s is not None:
            break
    return sim.metrics()


def test_every_shipped_scenario_is_planned() -> None:
    assert set(scenario_names()) == set(PLAN)


@pytest.mark.parametrize("name", sorted(PLAN))
def test_shipped_scenario_has_no_collision_while_moving(name: str) -> None:
    sc = load_scenario(name)
    horizon, must_finish = PLAN[name]
    sim = Simulation(sc)
    m = run_until_goal(sim, sc.sim.duration_s if horizon is None else horizon)
    assert m.collisions_moving == 0, (m.first_collision_s, m.min_separation_moving_m)
    assert m.fault_cycles == 0 or name in FAULTS_BY_DESIGN
    assert sum(m.modes.values()) == m.cycles
    if sc.humans:
        assert np.isfinite(m.min_separation_m)
    if must_finish:
        assert m.time_to_goal_s is not None, m.lines()
        assert m.time_to_goal_s <= sc.sim.duration_s
    if name == "standing_beside_path":  # the person does slow the robot, not stop it
        assert m.intervened_share > 0.0 and m.speed_scale_mean < 1.0
    if name == "empty_cell":
        assert m.failsafe_share == 0.0


def test_person_beside_path_on_the_papers_set_costs_less_than_a_stop() -> None:
    """On the paper's own set (Schepp et al. 2022 Table I, what its C++ shield ran), standing
    0.3 m beside the path delays the goal by less than the whole person-free task time and
    arrives before 4 s, where the paper's shield had not (the robot creeps past rather than
    waiting). The shipped scenario runs the sound set `bench_work` instead: its hands at 7 m/s
    cost 4.2x (docs/measurements/2026-11-27-bench-work-set.md)."""
    sc = load_scenario("standing_beside_path")
    paper = parse_scenario({**sc.model_dump(mode="json"), "human_params": "schepp2022_table1"})
    free = parse_scenario({**sc.model_dump(mode="json"), "humans": []})
    t_free = run_until_goal(Simulation(free), sc.sim.duration_s).time_to_goal_s
    t_person = run_until_goal(Simulation(paper), sc.sim.duration_s).time_to_goal_s
    assert t_free is not None and t_person is not None
    assert t_free <= t_person < min(2.0 * t_free, 4.0)


def test_randomised_adversarial_episodes_have_no_collision() -> None:
    summary = run_episodes(30, seed=2026, duration_s=1.2)
    assert summary.episodes == 30 and len(summary.metrics) == 30
    assert summary.collisions == 0, summary.colliding
    # the adversaries did come close and the shield did brake
    assert summary.min_separation_moving_m < 0.2
    assert summary.failsafe_share > 0.2


def _always_safe(
    y: np.ndarray,
    v: np.ndarray,
    dv: np.ndarray,
    age_s: np.ndarray,
    times_s: np.ndarray,
    robot_ends: np.ndarray,
    robot_radius: np.ndarray,
    widen_m: np.ndarray | None = None,
    caps: np.ndarray | None = None,
    *,
    models: int,
) -> SsmResult:
    H, K = y.shape[0], robot_ends.shape[0]
    free = np.ones((H, models, K), dtype=bool)
    P = 14
    return SsmResult(
        True, free, free.copy(), np.full((H, models), np.inf), np.ones((H, K, P), bool)
    )


@pytest.mark.parametrize("strategy", ["rigid", "limbs"])
def test_collision_counter_fires_without_a_real_shield(strategy: str) -> None:
    """The same adversary that never touches the shielded robot hits one whose verifier always
    answers 'safe' (the robot then runs its task blindly)."""
    sc = load_scenario("adversarial")
    data = sc.model_dump(mode="json")
    data["humans"][0]["strategy"] = strategy
    sc = parse_scenario(data)
    blind = Simulation(sc)
    n_models = len(blind.shield.verifier.models)
    blind.shield.verifier.verify = (  # type: ignore[method-assign]
        lambda *a: _always_safe(*a, models=n_models)
    )
    blind.shield._compiled = None  # the Python composition: the check it calls is the fake
    m = blind.run(2.0)
    assert m.collisions_moving > 0
    assert m.first_collision_s is not None and m.min_separation_moving_m <= 0.0
