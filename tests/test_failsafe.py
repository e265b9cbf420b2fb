"""Failsafe stops and shielded trajectories: limits, rest, path consistency, rigorous bounds.

Finite-difference tolerances: see the module docstring of ``tests/test_trajectory.py`` (divided
differences average the derivative with a non-negative unit kernel; only rounding is added).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from panda_limits import DT, HOME, PANDA, H, check_limits  # noqa: E402
from shielded_reference import shielded_reference
from stop_reference import plan_stop, straight_line_stop_duration

from sara_app.errors import RobotModelError
from sara_app.robot.failsafe import plan_joint_stop
from sara_app.robot.model import JointLimits
from sara_app.robot.shielded import shielded_trajectory
from sara_app.robot.trajectory import PathFollower, PathTrajectory

waypoint_sets = (
    st.integers(0, 2**32 - 1)
    .map(lambda seed: np.random.default_rng(seed).uniform(0.1, 0.9, (int(seed % 3) + 2, 7)))
    .map(lambda u: PANDA.q_min + (PANDA.q_max - PANDA.q_min) * (0.5 + 0.6 * (u - 0.5)))
)

CORNER = np.array(
    [HOME, HOME + [1.0, 0.5, 0, 0.5, 0, 0, 0.5], HOME + [1.0, -0.5, 0.5, -0.5, 0.3, -0.5, 0]]
)


def _moving_follower(wps: np.ndarray, n_steps: int, bd: float = 0.1) -> PathFollower:
    f = PathFollower(wps, PANDA, blend_distance=bd)
    for _ in range(n_steps):
        f.step(DT)
    return f


def _check_stop(path: PathTrajectory, stop, s0: float) -> None:
    T = stop.duration_s
    t = np.arange(0.0, T + 20 * H, H)
    s, sd, sdd = stop.path_samples(t)
    q, v, a = stop.sample(t)
    # stays on the path, s monotone, never past its end
    np.testing.assert_allclose(q, path.q(s), atol=1e-12)
    assert s[0] == pytest.approx(s0) and np.all(np.diff(s) >= -1e-12) and np.all(sd >= -1e-12)
    assert s[-1] <= path.length + 1e-9
    # ends at rest: zero velocity and acceleration at and after the end
    qe, ve, ae = stop.sample(np.array([T, T + 0.01, T + 1.0]))
    assert np.all(np.abs(ve) <= 1e-9) and np.all(np.abs(ae) <= 1e-7)
    np.testing.assert_allclose(qe[1], qe[0], atol=1e-12)
    np.testing.assert_allclose(qe[2], qe[0], atol=1e-12)
    # joint limits (sampled v and a directly, jerk by finite differences)
    assert np.all(np.abs(v) <= PANDA.v_max * (1 + 1e-9))
    assert np.all(np.abs(a) <= PANDA.a_max * (1 + 1e-9) + 1e-9)
    check_limits(q)


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(waypoint_sets, st.integers(1, 3000), st.sampled_from([0.03, 0.1, 0.3]))
def test_stop_from_followed_states(wps: np.ndarray, n_steps: int, bd: float) -> None:
    f = _moving_follower(wps, n_steps, bd)
    stop = plan_stop(f.path, f.s, f.sd, f.sdd, PANDA)
    _check_stop(f.path, stop, f.s)
    # the follower's held failsafe is valid too
    _check_stop(f.path, f.stop.advanced(0.0), f.s)


def _greedy_accel_only_stop(path: PathTrajectory, s0: float, v0: float, ds: float = 2e-4) -> float:
    """Duration of the stop that decelerates as hard as the joint acceleration limits allow at
    every point of the path, ignoring jerk and the initial s'': a reference for the gap."""
    s, v, t = s0, v0, 0.0
    a_max = PANDA.a_max
    while v > 1e-9:
        _, qs, qss = path.derivatives(s, 2)
        c = qss * v * v
        ok = np.abs(qs) > 1e-12
        b1 = (-a_max[ok] - c[ok]) / qs[ok]
        b2 = (a_max[ok] - c[ok]) / qs[ok]
        dec = float(np.max(np.minimum(b1, b2)))
        assert dec < 0
        v2 = v * v + 2 * dec * ds
        if v2 <= 0:
            return t + v / -dec
        vn = float(np.sqrt(v2))
        t += 2 * ds / (v + vn)
        v, s = vn, s + ds
    return t


def test_gap_to_time_optimal() -> None:
    """On straight stretches the stop is the time-optimal one (see the next test) and within a
    few per cent of the jerk-free reference (jerk ramps); in a sharp blend the worst-case
    decoupling costs more: measured here on the CORNER path (90 deg turn, d = 0.1 rad)."""
    f = PathFollower(CORNER, PANDA)
    ratios: dict[bool, list[float]] = {True: [], False: []}
    k = 0
    while not f.done:
        f.step(DT)
        k += 1
        if f.sd > 0.3 and k % 60 == 0:
            stop = plan_stop(f.path, f.s, f.sd, f.sdd, PANDA)
            ref = _greedy_accel_only_stop(f.path, f.s, f.sd)
            in_blend = bool(f.path.piece_is_blend[f.path.piece_index(stop.s_end)]) or bool(
                f.path.piece_is_blend[f.path.piece_index(f.s)]
            )
            ratios[in_blend].append(stop.duration_s / ref)
    straight, blend = np.array(ratios[False]), np.array(ratios[True])
    assert len(straight) > 10 and len(blend) >= 2
    assert np.all(straight >= 0.99) and np.all(straight <= 1.35)
    assert np.all(blend <= 8.0)


def test_straight_stop_is_time_optimal() -> None:
    path = PathTrajectory(np.array([HOME, HOME + [2.0, 1.0, 0, 0, 0, 0, 0]]), limits=PANDA)
    u = path.dq(0.3)
    for sd, sdd in ((0.5, 0.0), (2.0, 3.0), (1.5, -4.0), (0.01, 0.5)):
        stop = plan_stop(path, 0.3, sd, sdd, PANDA)
        assert stop.duration_s == pytest.approx(
            straight_line_stop_duration(sd, sdd, u, PANDA), rel=1e-8
        )
        _check_stop(path, stop, 0.3)


def test_stop_at_rest_and_errors() -> None:
    path = PathTrajectory(CORNER, limits=PANDA)
    rest = plan_stop(path, 0.7, 0.0, 0.0, PANDA)
    assert rest.duration_s == 0.0
    np.testing.assert_allclose(rest.sample(np.array([0.0, 1.0]))[0], path.q(np.array([0.7, 0.7])))
    with pytest.raises(RobotModelError, match="sd = nan"):
        plan_stop(path, 0.1, float("nan"), 0.0, PANDA)
    with pytest.raises(RobotModelError, match=r"s = 99\.0 rad; expected a path coordinate"):
        plan_stop(path, 99.0, 1.0, 0.0, PANDA)
    with pytest.raises(RobotModelError, match="path speed >= 0"):
        plan_stop(path, 0.1, -1.0, 0.0, PANDA)
    with pytest.raises(RobotModelError, match="no path-consistent stop"):
        plan_stop(path, 0.1, 50.0, 0.0, PANDA)  # far faster than the joints allow
    with pytest.raises(RobotModelError, match="no path-consistent stop"):
        plan_stop(path, path.length - 1e-3, 2.0, 0.0, PANDA)  # would run past the end
    with pytest.raises(RobotModelError, match="JointLimits"):
        plan_stop(path, 0.1, 1.0, 0.0, None)  # type: ignore[arg-type]


# ----------------------------------------------------------------------------------------------
# Shielded trajectory


def _dense_check_bounds(traj, path: PathTrajectory) -> None:
    prof = traj.step.profile.then(traj.stop.profile)
    for k in range(len(traj.times) - 1):
        t = np.linspace(traj.times[k], traj.times[k + 1], 201)
        s, sd, sdd = prof.evaluate(t)
        _, dq, d2q = path.derivatives(s, 2)
        v = np.abs(dq * sd[:, None])
        a = np.abs(d2q * (sd * sd)[:, None] + dq * sdd[:, None])
        assert np.all(v <= traj.v_bound[k]), (k, float(np.max(v - traj.v_bound[k])))
        assert np.all(a <= traj.a_bound[k]), (k, float(np.max(a - traj.a_bound[k])))


@settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(waypoint_sets, st.integers(0, 2500), st.sampled_from([None, 1, 7]))
def test_shielded_trajectory(wps: np.ndarray, n_steps: int, n_int: int | None) -> None:
    f = _moving_follower(wps, n_steps)
    before = (f.s, f.sd, f.sdd, f.t)
    traj = shielded_trajectory(f, DT, n_int)
    assert (f.s, f.sd, f.sdd, f.t) == before  # follower untouched
    K = len(traj.times) - 1
    n = 7
    assert traj.q.shape == traj.v.shape == traj.a.shape == (K + 1, n)
    assert traj.v_bound.shape == traj.a_bound.shape == (K, n)
    assert traj.failsafe_index == 1 and traj.times[1] == pytest.approx(DT)
    assert np.all(np.diff(traj.times) > 0) or K == 1
    if n_int is not None and traj.stop.duration_s > 0:
        assert K == 1 + n_int
    np.testing.assert_allclose(traj.q[0], f.state.q, atol=1e-12)
    np.testing.assert_allclose(traj.v[0], f.state.v, atol=1e-12)
    # the failsafe ends at rest on the path
    assert np.all(np.abs(traj.v[-1]) <= 1e-9) and np.all(np.abs(traj.a[-1]) <= 1e-7)
    np.testing.assert_allclose(traj.q, f.path.q(traj.s), atol=1e-12)
    _dense_check_bounds(traj, f.path)
    # the sample times are the documented grid
    m, T = K - 1, traj.stop.duration_s
    if m:
        np.testing.assert_array_equal(traj.times[2:], traj.times[1] + T * (np.arange(1, m + 1) / m))
    # ... and so do the joint samples and bounds, up to rounding (the compiled quartic is
    # summed in another order than the reference's matmul; tests/test_trajectory_kernels.py)
    ref = shielded_reference(f, DT, n_int)
    for name in ("q", "v", "a", "v_bound", "a_bound"):
        np.testing.assert_allclose(getattr(traj, name), getattr(ref, name), rtol=1e-12, atol=1e-13)
    # committing the verified step gives the state at the failsafe start
    f.commit(traj.step)
    np.testing.assert_allclose(f.state.q, traj.q[1], atol=1e-12)
    np.testing.assert_allclose(f.state.v, traj.v[1], atol=1e-12)
    # executing the failsafe from there (brake) follows the planned samples
    t_fs = traj.times[1:] - traj.times[1]
    q_fs, _, _ = traj.stop.sample(t_fs)
    np.testing.assert_allclose(q_fs, traj.q[1:], atol=1e-12)


def test_shielded_trajectory_dense_limits_and_brake() -> None:
    f = _moving_follower(CORNER, 650)  # approaching the blend, braking
    traj = shielded_trajectory(f, DT, max_interval_s=1e-3)
    prof = traj.step.profile.then(traj.stop.profile)
    t = np.arange(0, traj.duration_s + 10 * H, H)
    s, _, _ = prof.evaluate(t)
    check_limits(f.path.q(s))
    # braking along the held failsafe reproduces it
    f.commit(traj.step)
    qs = []
    for _ in range(int(traj.stop.duration_s / DT) + 2):
        qs.append(f.brake(DT).q)
    assert f.sd == 0.0 or f.done or f.sd < 1e-9
    np.testing.assert_allclose(qs[-1], traj.q[-1], atol=1e-9)
    with pytest.raises(RobotModelError, match="n_intervals"):
        shielded_trajectory(f, DT, 0)


def test_shielded_trajectory_at_rest() -> None:
    f = PathFollower(CORNER, PANDA)
    traj = shielded_trajectory(f, DT)
    assert traj.stop.duration_s > 0  # the first step already moves
    g = PathFollower(np.array([HOME, HOME]), PANDA)
    rest = shielded_trajectory(g, DT)
    assert len(rest.times) == 2 and np.all(rest.v == 0) and np.all(rest.v_bound <= 1e-12)


# ----------------------------------------------------------------------------------------------
# Joint-space stop


def test_joint_stop_straight_line_is_path_consistent() -> None:
    u = np.array([0.6, -0.3, 0.2, 0.5, 0.1, -0.4, 0.3])
    u /= np.linalg.norm(u)
    q0 = HOME.copy()
    stop = plan_joint_stop(q0, 2.0 * u, -1.5 * u, PANDA)
    assert stop.straight
    t = np.arange(0, stop.duration_s + 10 * H, H)
    q, v, a = stop.sample(t)
    d = (q - q0) @ u
    np.testing.assert_allclose(q, q0 + d[:, None] * u, atol=1e-12)  # on the line
    assert np.all(np.diff(d) >= -1e-12)  # monotone
    assert np.all(np.abs(v[-1]) <= 1e-12) and np.all(np.abs(a[-1]) <= 1e-9)
    check_limits(q, limits=_wide(PANDA))
    lower = straight_line_stop_duration(2.0, -1.5, u, PANDA)
    assert stop.duration_s == pytest.approx(lower, rel=1e-8)


def _wide(limits: JointLimits) -> JointLimits:
    """The joint-space stop may leave the position box (no path): only check the rates."""
    return JointLimits(
        q_min=limits.q_min - 10,
        q_max=limits.q_max + 10,
        v_max=limits.v_max,
        a_max=limits.a_max,
        j_max=limits.j_max,
    )


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_joint_stop_general_state(seed: int) -> None:
    rng = np.random.default_rng(seed)
    v0 = rng.uniform(-1, 1, 7) * PANDA.v_max
    a0 = rng.uniform(-1, 1, 7) * PANDA.a_max * 0.8
    # states whose speed would pass the limit anyway (v near v_max and still accelerating) are
    # not stoppable within the limits by any jerk-limited motion: scale the speed back
    peak = np.abs(v0 + a0 * np.abs(a0) / (2 * PANDA.j_max))
    v0 = v0 * np.minimum(1.0, PANDA.v_max / np.maximum(peak, 1e-12) * 0.999)
    stop = plan_joint_stop(HOME, v0, a0, PANDA)
    assert not stop.straight
    t = np.arange(0, stop.duration_s + 10 * H, H)
    q, v, a = stop.sample(t)
    np.testing.assert_allclose(v[0], v0)
    np.testing.assert_allclose(a[0], a0)
    assert np.all(np.abs(v[-1]) <= 1e-9) and np.all(np.abs(a[-1]) <= 1e-7)
    assert np.all(np.abs(a) <= PANDA.a_max * (1 + 1e-9))
    check_limits(q, limits=_wide(PANDA))
    # velocity bounds per interval are rigorous
    tt = np.linspace(0, stop.duration_s, 9)
    vb = stop.velocity_bounds(tt)
    for k in range(8):
        _, vk, _ = stop.sample(np.linspace(tt[k], tt[k + 1], 101))
        assert np.all(np.abs(vk) <= vb[k])


def test_joint_stop_errors_and_rest() -> None:
    rest = plan_joint_stop(HOME, np.zeros(7), np.zeros(7), PANDA)
    assert rest.duration_s == 0.0
    with pytest.raises(RobotModelError, match=r"v has shape \(6,\); expected \(7,\)"):
        plan_joint_stop(HOME, np.zeros(6), np.zeros(7), PANDA)
    with pytest.raises(RobotModelError, match=r"a\[2\] = nan"):
        plan_joint_stop(HOME, np.zeros(7), np.array([0, 0, np.nan, 0, 0, 0, 0]), PANDA)
