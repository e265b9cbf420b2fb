"""The combined speed-and-acceleration model (``HumanReach.combined``; the ball of
``reach_kernels.combined_ball``): sound on dense samples of motions that obey both bounds
(bang-bang accelerations with the speed saturating at v_max, straight pushes to the boundary,
random admissible motions), with velocity errors at their bound; never larger than R_ACC's or
R_VEL's sets in volume (each joint takes the smallest of three balls that are sound under both
bounds); R_VEL's ball without a velocity estimate."""

from __future__ import annotations

import math

import numpy as np
import pytest
from test_reach import (
    KINDS,
    T_END,
    T_START,
    _check_contained,
    _on_sphere,
    _pose,
    _rand_ball,
    _reach,
)
from test_reach import _simulate as simulate

from sara_app.human.reach_kernels import ROUND_PAD_M, combined_ball


def _ball_paths(rng, d_vec, dv, a, V, tau, n_paths):
    """Displacements at ``tau`` of admissible 1-joint motions from a true initial velocity within
    ``dv`` of the measured ``d_vec`` (and within V): bang-bang with projection onto |w| <= V,
    straight pushes (one direction throughout) and random piecewise-constant accelerations. A
    measurement farther than ``dv`` above V contradicts the speed bound: the motions then obey
    the acceleration bound only (the model falls back to it)."""
    steps = 400
    dt = tau / steps
    out = np.empty((n_paths, 3))
    consistent = np.linalg.norm(d_vec) <= V + dv
    for i in range(n_paths):
        while True:  # the true velocity: within dv of the measurement (and V, if it can be)
            w = d_vec + _on_sphere(rng, (3,), np.array(dv * rng.random() ** 0.2))
            if not consistent or np.linalg.norm(w) <= V:
                break
        kind = i % 3
        direction = _on_sphere(rng, (3,), np.array(1.0))
        switch = rng.integers(1, steps)
        x = np.zeros(3)
        for s in range(steps):
            if kind == 1 and s == switch:
                direction = _on_sphere(rng, (3,), np.array(1.0))
            elif kind == 2 and rng.random() < 0.05:
                direction = _on_sphere(rng, (3,), np.array(rng.random()))
            w_new = w + a * direction * dt
            n = np.linalg.norm(w_new)
            if n > V and consistent:
                w_new *= V / n  # the projection: the change stays within a dt
            x += 0.5 * (w + w_new) * dt
            w = w_new
        out[i] = x
    return out


@pytest.mark.parametrize("seed", range(6))
def test_the_combined_ball_contains_every_admissible_motion(seed: int) -> None:
    rng = np.random.default_rng(seed)
    misses, lens = 0, 0
    for _ in range(25):
        V = float(rng.uniform(0.5, 3.0))
        a = float(rng.uniform(2.0, 60.0))
        d = float(rng.choice([0.0, rng.uniform(0.0, V), V * rng.uniform(0.9, 1.0),
                              V * rng.uniform(1.0, 1.2)]))  # fmt: skip
        dv = float(rng.choice([0.0, rng.uniform(0.0, 0.5)]))
        tau = float(rng.uniform(0.01, 0.6))
        u = _on_sphere(rng, (3,), np.array(1.0))
        C, rho = combined_ball(d, dv, a, V, tau, True)
        x = _ball_paths(rng, d * u, dv, a, V, tau, 30)
        dist = np.linalg.norm(x - C * u, axis=1)
        misses += int((dist > rho + 1e-12).sum())
        # the speed bound bites: the lens (or the speed ball) is reached within tau
        lens += int(0.0 < d <= V + dv and dv + a * tau > math.sqrt(max(V * V - d * d, 0.0)))
        # the lens' radius is summed at sub-step ends: at most one sub-step's growth above
        # the speed ball's radius (the capsules take the smaller of the balls: next test)
        assert rho <= V * tau + ROUND_PAD_M or d > V + dv
    assert misses == 0 and lens > 5


def test_the_combined_ball_without_a_velocity_is_the_speed_ball() -> None:
    for d, dv in ((math.nan, 0.1), (1.0, math.inf), (math.inf, 0.0)):
        C, rho = combined_ball(d, dv, 20.0, 2.0, 0.3, True)
        assert C == 0.0 and rho == pytest.approx(0.6, abs=1e-8)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("seed", range(3))
def test_combined_capsules_contain_motion_under_both_bounds(kind: str, seed: int) -> None:
    """Whole skeletons: every joint at dense times of every interval (from the measurement,
    delay included) lies in its body parts' capsules grown by their half thickness."""
    rng = np.random.default_rng(300 + seed)
    reach = _reach(kind)
    p = reach.params
    H = 12
    y_true = _pose(rng, kind, H)
    J = y_true.shape[1]
    speeds = rng.uniform(0.0, 1.0, (H, J)) * p.v_max_mps[None]
    v_true = _on_sphere(rng, y_true.shape, speeds)
    dv = np.full((H, J), 0.2)
    y_meas = y_true + _rand_ball(rng, y_true.shape, np.full((H, J), p.delta_y_m))
    v_meas = v_true + _on_sphere(rng, y_true.shape, dv)
    o = reach.model("combined", y_meas, v_meas, dv, T_START, T_END)
    acc = reach.model("acc", y_meas, v_meas, dv, T_START, T_END)
    vel = reach.model("vel", y_meas, None, None, T_START, T_END)
    for k in range(len(T_START)):
        times = np.linspace(0, T_END[k] + p.delay_s, 80)
        paths = simulate(rng, y_true, v_true, p.a_max_mps2, p.v_max_mps, times)
        sel = times >= T_START[k] + p.delay_s
        assert _check_contained(reach, "combined", o.ends, o.radius, paths[sel], k) <= 1e-12

    # never larger than R_ACC's and R_VEL's sets
    def volume(occ, k):
        r = occ.radius[:, k]
        length = np.linalg.norm(occ.ends[:, k, :, 1] - occ.ends[:, k, :, 0], axis=-1)
        return float(np.sum(np.pi * r * r * length + 4.0 / 3.0 * np.pi * r**3))

    for k in range(len(T_START)):
        assert volume(o, k) <= min(volume(acc, k), volume(vel, k)) * (1 + 1e-9)
    # where both bounds bite (0.05-0.1 s after the measurement): a quarter below the smaller
    assert volume(o, 2) < 0.8 * min(volume(acc, 2), volume(vel, 2))


@pytest.mark.parametrize("kind", KINDS)
def test_a_part_mixing_a_joint_without_an_estimate_makes_no_claim(kind: str) -> None:
    """One joint without a velocity estimate: the parts that pair it with a joint that has one
    are unbounded (no claim); a part of that joint alone is R_VEL's capsule; the other parts
    are the capsules they get with every estimate known. Without any estimate every part is
    R_VEL's capsule."""
    rng = np.random.default_rng(7)
    reach = _reach(kind)
    p = reach.params
    y = _pose(rng, kind, 1)
    J = y.shape[1]
    v = _on_sphere(rng, y.shape, rng.uniform(0.0, 1.0, (1, J)) * p.v_max_mps[None])
    dv = np.full((1, J), 0.2)
    known = reach.combined(y, v, dv, T_START, T_END)
    vel = reach.vel(y, T_END)
    vel_r = np.broadcast_to(vel.radius, known.radius.shape)
    none = reach.combined(y, v, np.full((1, J), np.inf), T_START, T_END)
    np.testing.assert_allclose(none.radius, vel_r, rtol=0, atol=1e-8)
    pj = reach.skeleton.part_joints
    for j in range(J):
        dv_j = dv.copy()
        dv_j[0, j] = np.inf
        o = reach.combined(y, v, dv_j, T_START, T_END)
        mixed = np.broadcast_to((pj == j).any(axis=1) & (pj != j).any(axis=1), o.radius.shape)
        alone = np.broadcast_to((pj == j).all(axis=1), o.radius.shape)
        assert np.isinf(o.radius[mixed]).all()
        np.testing.assert_allclose(o.radius[alone], vel_r[alone], rtol=0, atol=1e-8)
        rest = ~mixed & ~alone
        np.testing.assert_array_equal(o.radius[rest], known.radius[rest])
