"""Waypoint inverse kinematics: round trips FK(IK(FK(q))) on random configurations and base
poses, solutions inside the joint limits, the Jacobian against finite differences, unreachable
targets reported with their residual, malformed input refused."""

from __future__ import annotations

from functools import cache

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sara_app.errors import InputError, UnknownNameError
from sara_app.geometry.poses import pose_from_xyz_rpy
from sara_app.robot.ik import (
    end_effector_frame,
    frame_jacobian,
    pose_error,
    pose_from_wxyz,
    solve_ik,
)
from sara_app.robot.model import RobotModel, load_robot

BASES = ((0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0.3, -0.2, 0.75, 0.1, -0.2, 1.2))


@cache
def robot(name: str, base: int) -> RobotModel:
    xyz, rpy = BASES[base][:3], BASES[base][3:]
    return load_robot(name, T_world_base=pose_from_xyz_rpy(xyz, rpy))  # type: ignore[arg-type]


def _random_q(r: RobotModel, rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(r.limits.q_min, r.limits.q_max)


@settings(max_examples=40, deadline=None)
@given(
    name=st.sampled_from(("panda", "ur5e")),
    base=st.integers(0, 1),
    seed=st.integers(0, 2**31 - 1),
    noise=st.floats(0.0, 0.5),
)
def test_round_trip_reaches_the_pose_inside_the_limits(
    name: str, base: int, seed: int, noise: float
) -> None:
    r = robot(name, base)
    rng = np.random.default_rng(seed)
    q = _random_q(r, rng)
    frame = end_effector_frame(r)
    T, _ = frame_jacobian(r, q, frame)
    q0 = q + rng.normal(scale=noise, size=q.shape)  # warm start near (may be outside limits)
    res = solve_ik(r, T, q0)
    assert res.converged, res
    assert np.all(res.q >= r.limits.q_min) and np.all(res.q <= r.limits.q_max)
    T_sol, _ = frame_jacobian(r, res.q, frame)
    e = pose_error(T, T_sol)
    assert np.linalg.norm(e[:3]) <= 1e-4 + 1e-12 and np.linalg.norm(e[3:]) <= 1e-3 + 1e-12
    assert res.position_error_m == pytest.approx(np.linalg.norm(e[:3]), abs=1e-12)
    # the solution also matches the model's own forward kinematics of the frame
    np.testing.assert_allclose(r.frame_pose(res.q, frame)[:3, 3], T[:3, 3], atol=1.1e-4)


def test_warm_start_at_the_solution_stays_there() -> None:
    r = robot("panda", 1)
    q = 0.5 * (r.limits.q_min + r.limits.q_max)
    T, _ = frame_jacobian(r, q, end_effector_frame(r))
    res = solve_ik(r, T, q)
    assert res.converged and res.iterations == 0 and np.array_equal(res.q, q)


def test_position_only_ignores_orientation() -> None:
    r = robot("panda", 0)
    rng = np.random.default_rng(3)
    q = _random_q(r, rng)
    frame = end_effector_frame(r)
    T, _ = frame_jacobian(r, q, frame)
    T_twisted = T.copy()
    T_twisted[:3, :3] = T[:3, :3] @ pin.exp3(np.array([0.0, 0.0, 2.5]))
    res = solve_ik(r, T_twisted, q, orientation=False)
    assert res.converged and res.position_error_m <= 1e-4
    full = solve_ik(r, T_twisted, q, restarts=0, max_iterations=1)
    assert full.rotation_error_rad > 1e-3  # the twisted target is not reached in one step


@pytest.mark.parametrize("name", ["panda", "ur5e"])
def test_frame_jacobian_matches_finite_differences(name: str) -> None:
    r = robot(name, 1)
    rng = np.random.default_rng(11)
    frame = end_effector_frame(r)
    h = 1e-6
    for _ in range(5):
        q = _random_q(r, rng)
        T, J = frame_jacobian(r, q, frame)
        for i in range(r.n_dof):
            dq = np.zeros(r.n_dof)
            dq[i] = h
            Tp, _ = frame_jacobian(r, q + dq, frame)
            Tm, _ = frame_jacobian(r, q - dq, frame)
            v = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
            w = (pin.log3(Tp[:3, :3] @ T[:3, :3].T) - pin.log3(Tm[:3, :3] @ T[:3, :3].T)) / (2 * h)
            np.testing.assert_allclose(J[:3, i], v, atol=1e-6)
            np.testing.assert_allclose(J[3:, i], w, atol=1e-6)


@pytest.mark.parametrize("name", ["panda", "ur5e"])
def test_unreachable_target_is_reported_not_faked(name: str) -> None:
    r = robot(name, 1)
    base = r.T_world_base[:3, 3]
    T = np.eye(4)
    T[:3, 3] = base + np.array([3.0, 0.0, 0.0])
    q0 = 0.5 * (r.limits.q_min + r.limits.q_max)
    res = solve_ik(r, T, q0, restarts=2)
    assert not res.converged
    assert np.all(res.q >= r.limits.q_min) and np.all(res.q <= r.limits.q_max)
    # the arm reaches about 1 m (Panda 0.855 m + hand, UR5e 0.85 m + tool): >= 1.5 m short
    assert res.position_error_m >= 1.5
    T_sol, _ = frame_jacobian(r, res.q, end_effector_frame(r))
    assert res.position_error_m == pytest.approx(np.linalg.norm(T[:3, 3] - T_sol[:3, 3]))
    assert res.starts == 3


def test_malformed_input_is_refused() -> None:
    r = robot("panda", 0)
    q = np.zeros(r.n_dof)
    with pytest.raises(InputError, match="T_world_target"):
        solve_ik(r, np.eye(3), q)
    bad = np.eye(4)
    bad[0, 0] = np.nan
    with pytest.raises(InputError, match="non-finite"):
        solve_ik(r, bad, q)
    skew = np.eye(4)
    skew[0, 1] = 0.5
    with pytest.raises(InputError, match="rotation"):
        solve_ik(r, skew, q)
    with pytest.raises(InputError, match="q0"):
        solve_ik(r, np.eye(4), np.zeros(3))
    with pytest.raises(UnknownNameError, match="panda_hand"):
        solve_ik(r, np.eye(4), q, frame="gripper")


@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4))
def test_pose_from_wxyz_is_pinocchios_quaternion(wxyz: list[float]) -> None:
    v = np.array(wxyz)
    if np.linalg.norm(v) <= 1e-9:
        with pytest.raises(InputError):
            pose_from_wxyz(v, np.zeros(3))
        return
    T = pose_from_wxyz(v, np.array([1.0, 2.0, 3.0]))
    u = v / np.linalg.norm(v)
    R = pin.Quaternion(u[0], u[1], u[2], u[3]).toRotationMatrix()
    np.testing.assert_allclose(T[:3, :3], R, atol=1e-12)
    np.testing.assert_allclose(T[:3, 3], [1, 2, 3])
