"""Link kinetic energies (Thumm et al. 2024 eq. 46-48) and link twists at samples.

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


def test_path_interval_energy_equals_the_numpy_formula() -> None:
    from sara_app.robot.energy import G_MARGIN, path_interval_energy_J

    rng = np.random.default_rng(22)
    for trial in range(50):
        K, L = int(rng.integers(1, 10)), int(rng.integers(1, 9))
        g = rng.uniform(0, 3, (K + 1, L))
        sd = rng.uniform(-1e-3, 2, K + 1)
        sd_max = np.maximum(np.maximum(sd[:-1], sd[1:]), rng.uniform(0, 2.5, K))
        E = 0.5 * sd[:, None] ** 2 * g * rng.uniform(0.99, 1.01, (K + 1, L))
        if trial % 5 == 0:
            [g, E][trial % 2][rng.integers(K + 1), rng.integers(L)] = np.nan
        m = np.maximum(np.maximum(np.abs(sd[:-1]), np.abs(sd[1:])), sd_max)
        ref = 0.5 * (1 + G_MARGIN) * (m * m)[:, None] * np.maximum(g[:-1], g[1:])
        ref = np.maximum(ref, np.maximum(E[:-1], E[1:]))
        ref = np.where(np.isnan(ref), np.inf, ref)
        got = path_interval_energy_J(g, E, sd, sd_max)
        np.testing.assert_allclose(got, ref, rtol=1e-15, atol=0)


def test_evaluate_path_equals_evaluate_of_the_joint_velocity(
    robot: tuple[RobotModel, LinkMotion],
) -> None:
    model, motion = robot
    q, dq = _samples(model, 6, seed=7)
    sd = np.array([0.0, 0.3, 1.0, 2.0, 1e-9, 0.7])
    plain = motion.evaluate(q, dq * sd[:, None])
    T, pd, w = plain.energy_J.copy(), plain.p1_dot.copy(), plain.omega.copy()
    path = motion.evaluate_path(q, dq, sd)
    np.testing.assert_allclose(path.energy_J, T, rtol=1e-12, atol=1e-300)
    np.testing.assert_allclose(path.p1_dot, pd, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(path.omega, w, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(path.g_J, 2.0 * motion.energies(q, dq), rtol=1e-12)
    sd[2] = np.nan
    bad = motion.evaluate_path(q, dq, sd)
    assert np.all(np.isinf(bad.energy_J[2, 1:])) and np.all(np.isnan(bad.p1_dot[2]))
    assert np.all(np.isfinite(bad.energy_J[[0, 1, 3]]))


def test_bounded_interval_energy_equals_the_numpy_formula(
    robot: tuple[RobotModel, LinkMotion],
) -> None:
    from sara_app.robot.energy import G_MARGIN, bounded_interval_energy_J

    model, motion = robot
    rng = np.random.default_rng(23)
    K = 4
    q, v = _samples(model, K + 1, seed=8)
    E = motion.energies(q, v).copy()
    qdd = rng.uniform(0, 20, (K, model.n_dof))
    dt = rng.uniform(0.001, 0.02, K)
    got = bounded_interval_energy_J(motion, q, E, qdd, dt)
    mask = support_mask(model)
    for k in range(K):
        delta = qdd[k] * dt[k] / 2
        for i in range(model.n_links):
            d = np.where(mask[i], delta, 0.0)
            ends = []
            for e in (k, k + 1):
                A = np.abs(model.mass_matrix(q[e]))
                x = np.sqrt(2 * E[e, i]) + np.sqrt(d @ A @ d)
                ends.append(0.5 * x * x)
            assert got[k, i] == pytest.approx((1 + G_MARGIN) * max(ends), rel=1e-10, abs=1e-14)
