"""The compiled shielded-trajectory sampling equals its numpy reference (the profile's and the
path's own methods) on random paths, states, speed caps, interval counts and fallback steps."""

from __future__ import annotations

import numpy as np
import pytest
from panda_limits import DT, PANDA
from shielded_reference import shielded_reference

from sara_app.robot.failsafe import BOUND_PAD
from sara_app.robot.shielded import shielded_trajectory
from sara_app.robot.trajectory import PathFollower

FIELDS = ("times", "q", "dq", "v", "a", "s", "sd", "sdd", "v_bound", "a_bound", "sd_max")


def _random_followers(seed: int, count: int) -> list[PathFollower]:
    """Followers at random points of random blended paths (some slowed by a speed cap)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        u = rng.uniform(0.2, 0.8, (int(rng.integers(2, 6)), 7))
        wps = PANDA.q_min + (PANDA.q_max - PANDA.q_min) * u
        f = PathFollower(wps, PANDA, blend_distance=float(rng.uniform(0.02, 0.3)))
        if rng.random() < 0.3:
            f.speed_cap = float(rng.uniform(0.05, 1.0))
        # stop short of a random piece start, so that the failsafe runs across it
        starts = f.path.piece_starts
        ahead = starts[1:] if len(starts) > 1 else [f.path.length]
        target = float(rng.choice(ahead)) - float(rng.uniform(0.0, 0.1))
        # or stop while still speeding up (the failsafe then peaks inside its first interval)
        steps = int(rng.integers(1, 40)) if rng.random() < 0.3 else 10**6
        while f.s < target and not f.done and steps > 0:
            f.step(DT * 4)
            steps -= 1
        out.append(f)
    return out


def _check_speed_peaks(traj) -> None:
    """``sd_max`` bounds the path speed densely sampled over every interval and is attained
    (up to the sampling of a quadratic peak)."""
    prof = traj.step.profile.then(traj.stop.profile)
    for k in range(len(traj.times) - 1):
        t = np.linspace(traj.times[k], traj.times[k + 1], 201)
        sd = prof.evaluate(t)[1]
        assert sd.max() <= traj.sd_max[k] * (1 + 1e-12) + 1e-15
        assert traj.sd_max[k] <= sd.max() + 1e-3 * max(abs(traj.sd_max[k]), 1e-3)


@pytest.mark.parametrize("seed", range(4))
def test_compiled_samples_equal_reference(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    crossings = peaks = 0
    for f in _random_followers(seed, 25):
        max_s = float(rng.choice([0.002, 0.01, 0.05]))
        n = None if rng.random() < 0.7 else int(rng.integers(1, 12))
        dt = float(rng.choice([0.001, 0.004, 0.02]))
        fast = shielded_trajectory(f, dt, n, max_interval_s=max_s)
        ref = shielded_reference(f, dt, n, max_interval_s=max_s)
        for name in FIELDS:
            x, y = getattr(fast, name), getattr(ref, name)
            assert x.shape == y.shape, name
            # the quartic is summed in another order than the reference's matmul: rounding only
            np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-13, err_msg=name)
        # the bounds never fall below the reference (they are the same rigorous formula)
        for name in ("v_bound", "a_bound"):
            assert np.all(getattr(fast, name) >= getattr(ref, name) * (1 - 1e-12) - 1e-15)
        k = np.searchsorted(f.path.piece_starts, ref.s, side="right")
        crossings += int(np.count_nonzero(np.diff(k)))
        peaks += int(np.any(ref.sd_max > np.maximum(ref.sd[:-1], ref.sd[1:])))
        _check_speed_peaks(fast)
    assert crossings > 0  # intervals that cross piece starts were exercised
    assert peaks > 0  # path-speed peaks inside intervals too


def test_fallback_step_equal_reference() -> None:
    """A step the follower cannot plan falls back to the held failsafe; sampled alike."""
    f = _random_followers(7, 1)[0]
    while f.sd < 0.2 and not f.done:
        f.step(DT)
    f.speed_cap = 0.0
    for _ in range(5):
        fast = shielded_trajectory(f, 0.004, max_interval_s=0.01)
        ref = shielded_reference(f, 0.004, max_interval_s=0.01)
        for name in FIELDS:
            np.testing.assert_allclose(
                getattr(fast, name), getattr(ref, name), rtol=1e-12, atol=1e-13
            )
        f.brake(0.004)


def test_intervals_across_many_pieces_equal_reference() -> None:
    """Short, nearly collinear segments (fast path speed) and one long failsafe interval: the
    intervals run over several pieces, so the maxima at inner piece starts decide the bounds."""
    rng = np.random.default_rng(5)
    n = 80
    wps = np.tile(np.array([0.0, 0.0, 0.0, -1.5, 0.0, 1.5, 0.0]), (n, 1))
    wps[:, 0] = np.linspace(-2.0, 2.0, n)
    wps[:, 1:3] += rng.uniform(-0.001, 0.001, (n, 2))
    f = PathFollower(wps, PANDA, blend_distance=0.01)
    many = 0
    for i in range(1200):
        f.step(DT)
        if i % 20:
            continue
        fast = shielded_trajectory(f, 0.004, 1)
        ref = shielded_reference(f, 0.004, 1)
        for name in FIELDS:
            x, y = getattr(fast, name), getattr(ref, name)
            np.testing.assert_allclose(x, y, rtol=1e-12, atol=1e-13, err_msg=name)
        k = np.searchsorted(f.path.piece_starts, ref.s, side="right")
        many += int(np.count_nonzero(np.diff(k) > 2))
    assert many > 0


def test_a_path_of_one_point_is_sampled_by_the_kernel_as_the_reference() -> None:
    """A task of one waypoint (the robot rests there): the kernel samples the path's single
    piece of length 0 exactly as the numpy reference: at rest at the point, bounds zero up to
    their rounding pad."""
    q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])
    f = PathFollower(q0[None], PANDA)
    assert f.path.n_pieces == 0
    fast = shielded_trajectory(f, 0.004, max_interval_s=0.01)
    ref = shielded_reference(f, 0.004, max_interval_s=0.01)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(fast, name), getattr(ref, name), err_msg=name)
    np.testing.assert_array_equal(fast.q, np.broadcast_to(q0, fast.q.shape))
    assert not fast.v.any() and not fast.a.any()
    assert fast.v_bound.max() <= BOUND_PAD and fast.a_bound.max() <= BOUND_PAD
