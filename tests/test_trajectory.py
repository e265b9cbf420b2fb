"""Joint-space task trajectories: blended paths, online follower, replanning, input errors.

Limit checks use finite differences of densely sampled positions. A k-th divided difference
with step h equals the k-th derivative averaged against a non-negative B-spline kernel of unit
mass (the trajectories are C2 with bounded, piecewise continuous jerk), so it never exceeds the
derivative's maximum over the window: the only slack needed is floating-point rounding of the
sampled positions, ``2^k * err_q / h^k`` with ``err_q`` a generous bound on the evaluation error
of ``q``.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from panda_limits import DT, HOME, PANDA, H, check_limits  # noqa: E402

from sara_app.errors import RobotModelError
from sara_app.robot.path import waypoints_ahead
from sara_app.robot.trajectory import (
    JointState,
    PathFollower,
    PathTrajectory,
    time_scaling,
)

waypoint_sets = (
    st.integers(0, 2**32 - 1)
    .map(lambda seed: np.random.default_rng(seed).uniform(0.1, 0.9, (int(seed % 3) + 2, 7)))
    .map(lambda u: PANDA.q_min + (PANDA.q_max - PANDA.q_min) * (0.5 + 0.6 * (u - 0.5)))
)


# ----------------------------------------------------------------------------------------------
# Path geometry


def test_path_ends_and_c2_continuity() -> None:
    wps = np.array(
        [HOME, HOME + [0.8, 0.4, 0, 0.3, 0, 0, 0.2], HOME + [0.8, -0.3, 0.5, -0.5, 0.3, -0.4, 0]]
    )
    path = PathTrajectory(wps, blend_distance=0.15, limits=PANDA)
    np.testing.assert_allclose(path.q(0.0), wps[0], atol=1e-12)
    np.testing.assert_allclose(path.q(path.length), wps[-1], atol=1e-12)
    assert path.n_pieces == 3 and list(path.piece_is_blend) == [False, True, False]
    for b in path.piece_starts[1:]:
        left = path.derivatives(b - 1e-9, 2)
        right = path.derivatives(b + 1e-9, 2)
        for lo, hi in zip(left, right, strict=True):
            np.testing.assert_allclose(lo, hi, atol=1e-6)
    # straight parts are arc-length parameterised, blends have |dq/ds| <= 1
    s = np.linspace(0, path.length, 2001)
    norms = np.linalg.norm(path.dq(s), axis=1)
    assert np.all(norms <= 1 + 1e-12)
    # corner cut by at most 3 d / 8
    dev = np.min(np.linalg.norm(path.q(s) - wps[1], axis=1))
    assert 0 < dev <= 3 * 0.15 / 8 + 1e-12


@settings(max_examples=25, deadline=None)
@given(waypoint_sets, st.floats(0.01, 0.5))
def test_path_derivatives_match_finite_differences(wps: np.ndarray, bd: float) -> None:
    path = PathTrajectory(wps, blend_distance=bd, limits=PANDA)
    s = np.linspace(0.0, path.length, 4001)
    q, dq, d2q, d3q = path.derivatives(s, 3)
    h = s[1] - s[0]
    # central differences, skipping samples next to piece boundaries (d3q jumps there)
    inner = np.ones(len(s), bool)
    for b in path.piece_starts:
        inner &= np.abs(s - b) > 3 * h
    mid = slice(1, -1)
    sel = inner[mid]
    # central differences have O(h^2) truncation error times the next derivative
    d3 = float(np.abs(d3q).max())
    for lower, upper, bound in ((q, dq, d3 + 1), (dq, d2q, d3 + 1), (d2q, d3q, None)):
        fd = (lower[2:] - lower[:-2]) / (2 * h)
        # d4q = 0 on every piece (quartic in s): the last difference is exact up to rounding
        atol = 1e-7 if bound is None else bound * h**2 + 1e-7
        np.testing.assert_allclose(fd[sel], upper[mid][sel], atol=atol * (1 + d3))
    # the path stays inside the box spanned by its waypoints (convex hull argument)
    assert np.all(q >= wps.min(axis=0) - 1e-12) and np.all(q <= wps.max(axis=0) + 1e-12)


# ----------------------------------------------------------------------------------------------
# Follower


@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(waypoint_sets, st.sampled_from([0.03, 0.1, 0.3]))
def test_follower_respects_limits_and_reaches_goal(wps: np.ndarray, bd: float) -> None:
    f = PathFollower(wps, PANDA, blend_distance=bd)
    t, s, sd, sdd = f.rollout(DT, 60.0, sample_dt=H)
    assert f.done, "follower did not reach the goal"
    assert f.fallback_steps == 0
    assert np.all(np.diff(s) >= -1e-12) and np.all(sd >= -1e-12)
    check_limits(f.path.q(s))
    end = f.state
    np.testing.assert_allclose(end.q, wps[-1], atol=1e-9)
    assert np.all(end.v == 0) and np.all(end.a == 0)
    # stays done
    assert f.step(DT).v.tolist() == [0.0] * 7


def test_straight_line_is_time_optimal_scalar_profile() -> None:
    """On a straight segment the path speed reaches the exact joint-limited cruise speed."""
    goal = HOME + np.array([2.0, 0, 0, 0, 0, 0, 0])
    f = PathFollower(np.array([HOME, goal]), PANDA)
    t, s, sd, sdd = f.rollout(DT, 10.0)
    assert f.done
    assert np.isclose(sd.max(), 2.175, rtol=1e-6)
    assert np.isclose(np.abs(sdd).max(), 15.0, rtol=1e-6)
    # time-optimal rest-to-rest for a long move: 2 * (a/j + v/a) ramps + cruise
    v, a, j, d = 2.175, 15.0, 7500.0, 2.0
    t_opt = d / v + v / a + a / j
    assert t[-1] <= t_opt + 2 * DT


def test_state_and_properties() -> None:
    f = PathFollower(np.array([HOME, HOME + 0.3]), PANDA)
    assert f.s == 0 and f.sd == 0 and f.sdd == 0 and not f.done
    st0 = f.state
    assert isinstance(st0, JointState) and np.allclose(st0.q, HOME)
    for _ in range(50):
        f.step(DT)
    assert f.s > 0 and f.sd > 0 and np.isclose(f.t, 50 * DT)
    starts, V = f.admissible_speed
    assert starts.shape == V.shape and np.all(V > 0)
    q, dq, d2q = f.path.derivatives(f.s, 2)
    np.testing.assert_allclose(f.state.v, dq * f.sd)
    np.testing.assert_allclose(f.state.a, d2q * f.sd**2 + dq * f.sdd)


def test_peek_does_not_mutate_and_commit_checks_state() -> None:
    f = PathFollower(np.array([HOME, HOME + 0.5]), PANDA)
    for _ in range(20):
        f.step(DT)
    before = (f.s, f.sd, f.sdd, f.t)
    step = f.peek(DT)
    assert (f.s, f.sd, f.sdd, f.t) == before
    g = f.copy()
    f.commit(step)
    g.step(DT)
    assert (f.s, f.sd, f.sdd) == (g.s, g.sd, g.sdd)
    with pytest.raises(RobotModelError, match="peek"):
        f.commit(step)


def _dense_run(f: PathFollower, n_steps: int) -> np.ndarray:
    qs = []
    local = np.arange(10) * H
    for _ in range(n_steps):
        st_ = f.peek(DT)
        s, _, _ = st_.profile.evaluate(local)
        qs.append(f.path.q(s))
        f.commit(st_)
    return np.concatenate(qs)


def test_replan_while_moving_is_smooth_and_keeps_moving() -> None:
    first = np.array([HOME, HOME + [1.2, 0.6, 0, 0.5, 0, 0, 0.5]])
    f = PathFollower(first, PANDA)
    q_before = _dense_run(f, 300)
    assert f.sd > 1.0
    state = f.state
    f.replan(np.array([HOME + [0.5, 1.0, -0.5, 0.4, 0.5, 0.5, 0.3], HOME]))
    after = f.state
    np.testing.assert_allclose(after.q, state.q, atol=1e-12)
    np.testing.assert_allclose(after.v, state.v, atol=1e-12)
    np.testing.assert_allclose(after.a, state.a, atol=1e-9)
    assert f.s == 0.0
    q_after = _dense_run(f, 400)
    q = np.concatenate([q_before, q_after])
    check_limits(q)
    speed = np.linalg.norm(np.diff(q_after, axis=0), axis=1) / H
    assert speed.min() > 0.3  # never stopped
    t, s, sd, sdd = f.rollout(DT, 30.0)
    assert f.done and f.fallback_steps == 0
    np.testing.assert_allclose(f.state.q, HOME, atol=1e-9)


@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(waypoint_sets, waypoint_sets, st.integers(50, 900))
def test_replan_at_random_times(first: np.ndarray, second: np.ndarray, when: int) -> None:
    f = PathFollower(first, PANDA)
    q1 = _dense_run(f, when)
    f.replan(second)
    q2 = _dense_run(f, 300)
    check_limits(np.concatenate([q1, q2]))
    f.rollout(DT, 60.0)
    assert f.done
    np.testing.assert_allclose(f.state.q, second[-1], atol=1e-9)


def test_replan_same_goal_is_noop_and_at_rest_starts_here() -> None:
    goal = HOME + 0.4
    f = PathFollower(np.array([HOME, goal]), PANDA)
    for _ in range(100):
        f.step(DT)
    path = f.path
    f.replan(goal[None, :])  # same end point: nothing changes
    assert f.path is path
    f.rollout(DT, 10.0)
    other = HOME - 0.2
    f.replan(other[None, :])
    np.testing.assert_allclose(f.path.q(0.0), goal, atol=1e-12)
    f.rollout(DT, 10.0)
    np.testing.assert_allclose(f.state.q, other, atol=1e-9)


def test_frequent_replans_of_a_drifting_goal_converge() -> None:
    f = PathFollower(np.array([HOME, HOME + [0.6, 0.5, 0, 0.3, 0, 0.4, 0.2]]), PANDA)
    base = HOME + np.array([0.5, 1.0, -0.5, 0.5, 0.5, 0.5, 0.3])
    qs = []
    for i in range(4000):
        if i % 5 == 0:
            f.replan((base + [0.002 * np.sin(i / 300), 0, 0, 0, 0, 0, 0])[None, :])
        qs.append(f.step(DT).q)
        if f.done:
            break
    assert f.done
    np.testing.assert_allclose(f.state.q[1:], base[1:], atol=1e-9)
    check_limits(np.array(qs), h=DT)


def test_time_scaling_offline() -> None:
    path = PathTrajectory(
        np.array([HOME, HOME + 0.5, HOME + [0.5, 0, 0.5, 0, 0, 0, 0]]), limits=PANDA
    )
    t, s, sd, sdd = time_scaling(path, PANDA, dt=DT)
    assert t[0] == 0 and np.all(np.diff(t) > 0)
    assert s[0] == 0 and np.isclose(s[-1], path.length) and np.all(np.diff(s) >= 0)
    assert sd[-1] == 0 and sdd[-1] == 0


# ----------------------------------------------------------------------------------------------
# Errors


def test_waypoint_errors_name_index_and_joint() -> None:
    bad = np.array([HOME, HOME.copy()])
    bad[1, 3] = 0.5  # joint 3 must stay below -0.0698
    with pytest.raises(RobotModelError, match=r"waypoint 1 joint 3 = 0\.5 rad is outside"):
        PathFollower(bad, PANDA)
    nan = np.array([HOME, HOME.copy()])
    nan[1, 2] = np.nan
    with pytest.raises(RobotModelError, match="waypoint 1 joint 2 is nan"):
        PathTrajectory(nan)
    with pytest.raises(RobotModelError, match=r"shape \(7,\); expected \(W, 7\)"):
        PathFollower(HOME, PANDA)
    with pytest.raises(RobotModelError, match="6 joints"):
        PathFollower(np.zeros((2, 6)), PANDA)
    with pytest.raises(RobotModelError, match="cannot be read"):
        PathTrajectory([[0.0, "x"]])
    with pytest.raises(RobotModelError, match="blend_distance"):
        PathTrajectory(np.array([HOME, HOME + 0.1]), blend_distance=0.0)
    f = PathFollower(np.array([HOME, HOME + 0.1]), PANDA)
    with pytest.raises(RobotModelError, match="dt"):
        f.step(0.0)
    with pytest.raises(RobotModelError, match="dt"):
        f.step(float("nan"))
    out = HOME.copy()
    out[5] = 4.0
    with pytest.raises(RobotModelError, match=r"waypoint 0 joint 5 .* unreachable"):
        f.replan(out[None, :])
    with pytest.raises(RobotModelError, match="tangential_share"):
        PathFollower(np.array([HOME, HOME + 0.1]), PANDA, tangential_share=1.0)
    with pytest.raises(RobotModelError, match="JointLimits"):
        PathFollower(np.array([HOME, HOME + 0.1]), {"v_max": 1})  # type: ignore[arg-type]


def test_degenerate_paths() -> None:
    f = PathFollower(np.array([HOME, HOME]), PANDA)
    assert f.path.length == 0 and f.done
    np.testing.assert_allclose(f.step(DT).q, HOME)
    single = PathTrajectory(HOME[None, :])
    assert single.length == 0 and np.allclose(single.q(np.array([0.0, 1.0])), HOME)


def test_waypoints_ahead_are_those_after_the_segment_the_robot_stands_on() -> None:
    """Brute force: points sampled on each segment of random polylines (corners excluded) have
    exactly the waypoints after that segment ahead; a point at a corner has the later
    segment's; a single waypoint is ahead of anything."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        w = rng.uniform(-2.0, 2.0, size=(int(rng.integers(2, 6)), 7))
        for j in range(len(w) - 1):
            for t in (0.05, 0.5, 0.95):
                q = w[j] + t * (w[j + 1] - w[j])
                d = [np.linalg.norm(q - (w[i] + np.clip(np.dot(q - w[i], w[i + 1] - w[i])
                     / np.dot(w[i + 1] - w[i], w[i + 1] - w[i]), 0, 1) * (w[i + 1] - w[i])))
                     for i in range(len(w) - 1)]  # fmt: skip
                if len(d) > 1 and sorted(d)[1] < 1e-9:  # a polyline crossing itself here
                    continue
                np.testing.assert_array_equal(waypoints_ahead(w, q), w[j + 1 :])
        for j in range(1, len(w) - 1):  # at a corner: the segment leaving it
            np.testing.assert_array_equal(waypoints_ahead(w, w[j]), w[j + 1 :])
    single = rng.uniform(size=(1, 7))
    np.testing.assert_array_equal(waypoints_ahead(single, np.zeros(7)), single)
