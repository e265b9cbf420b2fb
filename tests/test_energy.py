"""Link kinetic energies (seed 003 eq. 46-48) and link twists at samples.

References: pinocchio's own ``computeKineticEnergy`` with the distal joint velocities zeroed (an
independent path through the RNEA-style kinematics), ``RobotModel.mass_matrix``, and finite
differences of the capsule ends for the twists.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from sara_app.errors import InputError
from sara_app.robot.energy import LinkMotion, interval_energy_J, support_mask
from sara_app.robot.model import RobotModel, load_robot


def _base_pose() -> np.ndarray:
    c, s = np.cos(0.7), np.sin(0.7)
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = [0.4, -0.3, 0.75]
    return T


@pytest.fixture(scope="module", params=["panda", "ur5e"])
def robot(request: pytest.FixtureRequest) -> tuple[RobotModel, LinkMotion]:
    model = load_robot(request.param, T_world_base=_base_pose())
    return model, LinkMotion(model)


def _samples(model: RobotModel, S: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    lim = model.limits
    q = rng.uniform(np.maximum(lim.q_min, -3), np.minimum(lim.q_max, 3), (S, model.n_dof))
    return q, rng.uniform(-1, 1, (S, model.n_dof)) * lim.v_max


def test_last_link_energy_is_the_whole_kinetic_energy(robot: tuple[RobotModel, LinkMotion]) -> None:
    model, motion = robot
    q, v = _samples(model, 8)
    T = motion.energies(q, v)
    for s in range(8):
        M = model.mass_matrix(q[s])
        assert T[s, -1] == pytest.approx(0.5 * v[s] @ M @ v[s], rel=1e-10)
        assert T[s, 0] == 0.0  # base link: no joint moves it


def test_truncation_matches_pinocchio_energy_with_distal_joints_frozen(
    robot: tuple[RobotModel, LinkMotion],
) -> None:
    model, motion = robot
    q, v = _samples(model, 6, seed=1)
    T = motion.energies(q, v)
    data = model.pin_model.createData()
    mask = support_mask(model)
    for s in range(6):
        for i in range(model.n_links):
            v_trunc = np.where(mask[i], v[s], 0.0)
            ref = pin.computeKineticEnergy(model.pin_model, data, q[s], v_trunc)
            assert T[s, i] == pytest.approx(ref, rel=1e-9, abs=1e-12)


def test_distal_joint_motion_gives_upstream_links_zero_energy(
    robot: tuple[RobotModel, LinkMotion],
) -> None:
    model, motion = robot
    q, _ = _samples(model, 1, seed=2)
    v = np.zeros((1, model.n_dof))
    v[0, -1] = 1.0  # only the last joint moves
    T = motion.energies(q, v)[0]
    mask = support_mask(model)
    moved = mask[:, -1]
    assert np.all(T[~moved] == 0.0)
    assert np.all(T[moved] > 0.0)
    # mask is the chain: link i carried by joint m is moved by joints 1..m
    assert np.all(np.diff(mask.astype(int), axis=1) <= 0)


def test_twists_match_finite_differences(robot: tuple[RobotModel, LinkMotion]) -> None:
    model, motion = robot
    q, v = _samples(model, 4, seed=3)
    res = motion.evaluate(q, v)
    h = 1e-6
    ends_p = np.array([model.link_capsules(qq)[0] for qq in q + h * v])
    ends_m = np.array([model.link_capsules(qq)[0] for qq in q - h * v])
    fd = (ends_p - ends_m) / (2 * h)  # (S, L, 2, 3)
    assert np.allclose(res.ends, np.array([model.link_capsules(qq)[0] for qq in q]), atol=1e-9)
    assert np.allclose(res.p1_dot, fd[:, :, 0], atol=1e-6)
    lever = res.ends[:, :, 1] - res.ends[:, :, 0]
    assert np.allclose(fd[:, :, 1] - fd[:, :, 0], np.cross(res.omega, lever), atol=1e-6)


def test_bad_samples_are_infinite_energy_not_errors(robot: tuple[RobotModel, LinkMotion]) -> None:
    model, motion = robot
    q, v = _samples(model, 3, seed=4)
    q[1, 2] = np.nan
    v[2, 0] = np.inf
    res = motion.evaluate(q, v)
    assert np.all(np.isinf(res.energy_J[1:, 1:]))
    assert np.all(np.isnan(res.p1_dot[1:])) and np.all(np.isfinite(res.p1_dot[0]))
    with pytest.raises(InputError, match="expected equal shapes"):
        motion.evaluate(q[:, :2], v)


def test_interval_energy_is_the_larger_end() -> None:
    T = np.array([[0.0, 1.0], [2.0, 0.5], [1.0, 3.0]])
    assert np.array_equal(interval_energy_J(T), [[2.0, 1.0], [2.0, 3.0]])
