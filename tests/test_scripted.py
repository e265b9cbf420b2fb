"""Scripted human motions (``sara_app.human.scripted``): every joint's finite-difference speed and
acceleration stay within the parameter set's bounds, and the limbs are rigid (the R_POS model's
assumption), for the shipped scenarios and for generated motions."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.scripted import (
    FOREARM_M,
    UPPER_ARM_M,
    ScriptedMotion,
    build_motion,
    motion_bounds,
)
from sara_app.human.skeleton import FULL_JOINTS
from sara_app.scenario import MOTIONS, ScriptedHuman, load_scenario, scenario_names
from sara_app.sim.motions import Scripted, make_motion

J = {n: i for i, n in enumerate(FULL_JOINTS)}
LIMBS = {
    "l_upper_arm": ("l_shoulder", "l_elbow"),
    "r_upper_arm": ("r_shoulder", "r_elbow"),
    "l_forearm": ("l_elbow", "l_wrist"),
    "r_forearm": ("r_elbow", "r_wrist"),
    "l_thigh": ("l_hip", "l_knee"),
    "r_thigh": ("r_hip", "r_knee"),
    "l_shin": ("l_knee", "l_ankle"),
    "r_shin": ("r_knee", "r_ankle"),
    "trunk": ("neck", "pelvis"),
    "neck_head": ("neck", "head"),
}
FD_SLACK = 1e-6  # relative: round-off of the finite differences

SCRIPTED = [
    (name, h)
    for name in scenario_names()
    for h in load_scenario(name).humans
    if isinstance(h, ScriptedHuman)
]
PARAMS = to_reach_params(load_param_set("schepp2022_table1"), "full")


def _samples(m: ScriptedMotion, dt: float) -> np.ndarray:
    t = np.arange(m.start_s - 0.1, m.start_s + m.duration_s + 0.1, dt)
    return np.stack([m.pose(ti) for ti in t])


def _limb_lengths(ys: np.ndarray) -> np.ndarray:
    """``(S, limbs)`` segment lengths of the sampled poses ``(S, 15, 3)``."""
    a = ys[:, [J[x] for x, _ in LIMBS.values()]]
    b = ys[:, [J[y] for _, y in LIMBS.values()]]
    return np.linalg.norm(a - b, axis=-1)


def _check_motion(m: ScriptedMotion, v_max: np.ndarray, a_max: np.ndarray, dt: float) -> None:
    v, a = motion_bounds(m, dt)
    assert np.all(np.isfinite(v)) and np.all(np.isfinite(a))
    assert np.all(v <= v_max * (1 + FD_SLACK)), (v / v_max).max()
    assert np.all(a <= a_max * (1 + FD_SLACK)), (a / a_max).max()
    lengths = _limb_lengths(_samples(m, 4 * dt))
    np.testing.assert_allclose(lengths, np.broadcast_to(lengths[0], lengths.shape), atol=1e-9)
    arm = lengths[0, list(LIMBS).index("l_upper_arm")], lengths[0, list(LIMBS).index("l_forearm")]
    np.testing.assert_allclose(arm, (UPPER_ARM_M, FOREARM_M), atol=1e-12)


@pytest.mark.parametrize(("scenario", "human"), SCRIPTED, ids=[f"{n}-{h.id}" for n, h in SCRIPTED])
def test_shipped_scripted_motions_respect_bounds(scenario: str, human: ScriptedHuman) -> None:
    sc = load_scenario(scenario)
    params = to_reach_params(sc.param_set(), "full")
    src = make_motion(human, params)
    assert isinstance(src, Scripted)
    m = src.motion
    assert m.duration_s > 0
    _check_motion(m, params.v_max_mps, params.a_max_mps2, 1e-3)
    # the motion actually moves unless it is a stand
    ys = _samples(m, 0.01)
    travel = np.linalg.norm(ys - ys[0], axis=-1).max()
    assert (travel > 0.1) == (human.motion != "stand")


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from(MOTIONS),
    st.tuples(st.floats(-2.5, 2.5), st.floats(-2.5, 2.5)),
    st.tuples(st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.floats(0.0, 1.8)),
    st.floats(0.5, 1.0),
    st.floats(0.0, 2.0),
)
def test_generated_motions_respect_bounds(
    motion: str,
    xy: tuple[float, float],
    target: tuple[float, float, float],
    speed_scale: float,
    start_s: float,
) -> None:
    v_max, a_max = PARAMS.v_max_mps, PARAMS.a_max_mps2
    m = build_motion(motion, xy, target, v_max, a_max, speed_scale=speed_scale, start_s=start_s)
    _check_motion(m, v_max * speed_scale, a_max * speed_scale, 3e-3)
    # held before the start and after the end
    np.testing.assert_array_equal(m.pose(start_s - 1.0), m.pose(start_s))
    end = start_s + m.duration_s
    np.testing.assert_allclose(m.pose(end + 1.0), m.pose(end), atol=1e-12)
