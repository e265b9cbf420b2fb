"""The Liu et al. 2022 study: qualitative findings, Table 1 format, plots, eq. 7 sampling."""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.safety.jssa import JssaController, JssaParams
from sara_app.studies import jssa_study as st


@pytest.fixture(scope="module")
def scenario():
    sc = st.seed_scenario()
    sc.duration_s = 4.5  # covers approach, stop and retreat of the scripted walk
    return sc


@pytest.fixture(scope="module")
def runs(scenario):
    out = {}
    for lam in ((6.0, 6.0), (8.0, 6.0), (6.0, 8.0)):
        params = JssaParams(lambda_1=lam[0], lambda_2=lam[1])
        out[lam] = st.summarize(st.run_episode(scenario, JssaController(scenario.robot, params)))
    return out


def test_larger_lambda1_triggers_earlier_and_keeps_more_distance(runs) -> None:
    small, large = runs[(6.0, 6.0)], runs[(8.0, 6.0)]
    assert large.first_trigger_s < small.first_trigger_s
    assert large.min_distance_m > small.min_distance_m
    assert small.fallbacks == large.fallbacks == 0


def test_larger_lambda2_smooths_accelerations(runs) -> None:
    small, large = runs[(6.0, 6.0)], runs[(6.0, 8.0)]
    assert large.mean_robot_acc < small.mean_robot_acc
    assert large.mean_rel_acc < small.mean_rel_acc
    assert large.min_distance_m < small.min_distance_m  # the paper's Table 1 trend as well


def test_ssa_saturates_jerk_more_often_than_jssa(scenario) -> None:
    res = st.compare_ssa(scenario, JssaParams(jerk_scale=0.01))
    assert res["SSA"][0].saturated_share > 5 * max(res["JSSA"][0].saturated_share, 1e-3)
    for _, trace in res.values():
        assert np.all(np.abs(trace.jerk) <= trace.jerk_hi * (1 + 1e-12))


def test_table_format_and_plot(scenario, tmp_path) -> None:
    sc = st.Scenario(scenario.robot, scenario.q_home, scenario.human, duration_s=0.8)
    table = st.sensitivity_table(sc, (6.0, 7.0))
    text = st.format_table(table)
    assert len(table) == 4 and text.count("(") >= 4 and "lambda_2" in text
    tr = st.run_episode(sc, JssaController(sc.robot, JssaParams()))
    png = tmp_path / "p.png"
    st.plot_trace(tr, str(png), "t", 0.05)
    assert png.stat().st_size > 1000
    assert len(st.format_trace(tr).splitlines()) > 2


def test_feasibility_sampling_finds_boundary_states() -> None:
    from sara_app.studies.jssa_feasibility import check_feasibility

    robot = st.panda_on_table()
    ok = check_feasibility(robot, JssaParams(lambda_1=3.0, lambda_2=1.0), n_samples=60, seed=1)
    assert ok.n_states > 10 and ok.n_violations == 0 and ok.worst_phi_rate <= 0
    # with 1 % of the jerk bounds the same index is no longer always feasible
    weak = check_feasibility(
        robot, JssaParams(lambda_1=3.0, lambda_2=1.0, jerk_scale=0.01), n_samples=300, seed=0
    )
    assert weak.n_violations > 0 and weak.worst_phi_rate > 0
