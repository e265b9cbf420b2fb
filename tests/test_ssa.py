"""SSA baseline (Liu et al. 2022 Sec. 4.3): acceleration-level projection, saturated jerk."""

from __future__ import annotations

import numpy as np

from sara_app.safety.jssa import JssaParams
from sara_app.safety.ssa import SsaController
from sara_app.studies.jssa_study import PANDA_HOME, panda_on_table, rigid_human


def test_ssa_output_within_jerk_bounds_and_counts_saturation() -> None:
    robot = panda_on_table()
    ctrl = SsaController(robot, JssaParams(lambda_1=3.0, jerk_scale=0.01))
    assert ctrl.params.lambda_2 == 0.0
    rng = np.random.default_rng(0)
    n_sat = 0
    for _ in range(30):
        h = rigid_human(
            np.array([rng.uniform(1.0, 1.6), rng.uniform(-0.4, 0.4)]), np.pi,
            np.array([-rng.uniform(0.3, 1.5), 0.0]), np.zeros(2),
        )  # fmt: skip
        qd, qdd = rng.normal(0, 0.2, 7), rng.normal(0, 0.5, 7)
        res = ctrl.step(PANDA_HOME, qd, qdd, rng.normal(0, 5, 7), h.ends, h.radius, h.vel, 0.008)
        assert np.all(np.abs(res.jerk) <= ctrl.jerk_hi * (1 + 1e-12))
        n_sat += res.reason == "jerk saturated"
    assert ctrl.stats["saturated"] == n_sat > 0


def test_ssa_with_ample_jerk_keeps_its_margin_on_the_scripted_walk() -> None:
    """Unsaturated (full Panda jerk bounds), the SSA projection alone keeps d > d_min."""
    from sara_app.studies.jssa_study import run_episode, seed_scenario, summarize

    sc = seed_scenario()
    sc.duration_s = 4.0
    ctrl = SsaController(sc.robot, JssaParams(lambda_1=3.0, d_min_m=0.05))
    s = summarize(run_episode(sc, ctrl))
    assert s.duration_s > 0.2 and s.saturated_share == 0.0 and s.fallbacks == 0
    assert s.min_distance_m > 0.05
