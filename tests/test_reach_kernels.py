"""The compiled reachability kernels behind ``HumanReach.pos / vel / iso13855 / acc`` against a
plain numpy transcription of the formulas in the method docstrings (the implementation before
the kernels), on random skeletons, velocities, error bounds (including ``inf``: no velocity
estimate) and intervals, for one and several humans. Soundness of the models themselves is
tested by sampling in ``test_reach.py``."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sara_app.errors import InputError
from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach

SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
REACH = {
    kind: HumanReach(to_reach_params(load_param_set("schepp2022_table1"), kind))
    for kind in ("full", "upper")
}


def ref_static(r: HumanReach, y, t_end, base, speed):
    tau = t_end + r.params.delay_s
    return y[:, r.skeleton.part_joints], tau[:, None] * speed + base


def ref_vel_disp(r: HumanReach, y, t_end):
    """R_VEL with a displacement table: base + min(v_max tau, D(tau)), D per part the larger of
    its joints' table cells (cell ceil(tau / step) - 1; past the table its last value + v_max x
    the rest)."""
    p, sk = r.params, r.skeleton
    tau = t_end + p.delay_s
    D = np.maximum(p.disp_max_m[sk.part_joints[:, 0]], p.disp_max_m[sk.part_joints[:, 1]])
    n, step = D.shape[1], p.disp_step_s
    cell = np.maximum(np.ceil(tau / step).astype(int) - 1, 0)
    inside = D[:, np.minimum(cell, n - 1)].T  # (K, P)
    past = D[:, -1][None, :] + r.vel_speed[None, :] * (tau - n * step)[:, None]
    d = np.where((cell < n)[:, None], inside, past)
    return y[:, sk.part_joints], np.minimum(tau[:, None] * r.vel_speed, d) + r.vel_base


def ref_pos(r: HumanReach, y, t_end):
    sk, p = r.skeleton, r.params
    tau = t_end + p.delay_s
    lengths = np.zeros((y.shape[0], r.n_limbs))
    for i, chain in enumerate(sk.limb_chains):
        for a, b in zip(chain[:-1], chain[1:]):
            lengths[:, i] += np.linalg.norm(y[:, b] - y[:, a], axis=-1)
    radius = np.broadcast_to(tau[:, None] * r.pos_rspeed + r.pos_rbase, (y.shape[0],) + (
        tau.shape[0], len(r.pos_rbase))).copy()  # fmt: skip
    radius[:, :, : r.n_limbs] += lengths[:, None, :]
    return y[:, r.pos_ends], radius


def ref_acc(r: HumanReach, y, v, dv, t_start, t_end):
    p, sk = r.params, r.skeleton
    ta, tb = t_start + p.delay_s, t_end + p.delay_s
    R = dv[:, None, :] * tb[:, None] + (0.5 * p.a_max_mps2 * (tb * tb)[:, None] + p.delta_y_m)
    grow = R + np.linalg.norm(v, axis=-1)[:, None, :] * (0.5 * (tb - ta))[:, None]
    ja, jb = sk.part_joints[:, 0], sk.part_joints[:, 1]
    ball = ja == jb
    radius = np.where(ball, R[:, :, ja], np.maximum(grow[:, :, ja], grow[:, :, jb]))
    radius = radius + p.half_thickness_m
    mid = 0.5 * (ta + tb)
    at = lambda t, j: y[:, None, j] + v[:, None, j] * t[None, :, None, None]  # noqa: E731
    e0 = np.where(ball[None, None, :, None], at(ta, ja), at(mid, ja))
    e1 = np.where(ball[None, None, :, None], at(tb, jb), at(mid, jb))
    return np.stack([e0, e1], axis=3), radius


@st.composite
def inputs(draw: st.DrawFn) -> dict:
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    kind = draw(st.sampled_from(["full", "upper"]))
    J = REACH[kind].skeleton.n_joints
    H, K = draw(st.integers(1, 4)), draw(st.integers(1, 6))
    y = rng.normal(scale=0.5, size=(H, J, 3)) + [0.0, 0.0, 1.0]
    v = rng.normal(scale=draw(st.sampled_from([0.0, 0.5, 3.0])), size=(H, J, 3))
    dv = rng.uniform(0.0, 0.5, size=(H, J))
    if rng.random() < 0.3:
        dv[rng.integers(H), rng.integers(J)] = np.inf
    t0 = np.cumsum(rng.uniform(0.0, 0.05, K))
    return dict(kind=kind, y=y, v=v, dv=dv, ts=t0, te=t0 + rng.uniform(0.0, 0.05, K))


def _close(a: np.ndarray, b: np.ndarray) -> None:
    np.testing.assert_allclose(np.broadcast_to(a, b.shape), b, rtol=1e-13, atol=1e-14)


@SETTINGS
@given(inputs())
def test_kernels_equal_numpy_formulas(c: dict) -> None:
    r = REACH[c["kind"]]
    y, v, dv, ts, te = c["y"], c["v"], c["dv"], c["ts"], c["te"]
    H, K = y.shape[0], te.shape[0]
    for occ, (ends, radius) in (
        (r.vel(y, te), ref_static(r, y, te, r.vel_base, r.vel_speed)),
        (r.iso13855(y, te), ref_static(r, y, te, r.iso_base, r.iso_speed)),
    ):
        _close(occ.ends[:, 0], ends)
        _close(occ.radius[0], radius)
        assert occ.ends.shape == (H, 1) + ends.shape[1:] and occ.radius.shape == (
            1,
            K,
            ends.shape[1],
        )
    occ = r.pos(y, te)
    ends, radius = ref_pos(r, y, te)
    _close(occ.ends[:, 0], ends)
    _close(occ.radius, radius)
    occ = r.acc(y, v, dv, ts, te)
    ends, radius = ref_acc(r, y, v, dv, ts, te)
    _close(occ.ends, ends)
    _close(occ.radius, radius)


def _with_table(kind: str, seed: int) -> HumanReach:
    """Table I's set with a random non-decreasing displacement table (5 cells of 20 ms), some
    of it above v_max tau (then v_max tau holds)."""
    from sara_app.human.params import DisplacementBound
    from sara_app.human.skeleton import FULL_JOINTS

    rng = np.random.default_rng(seed)
    rows = {j: np.cumsum(rng.uniform(0.0, 0.08, 5)).round(3).tolist() for j in FULL_JOINTS}
    ps = load_param_set("schepp2022_table1").model_copy(
        update={"displacement": DisplacementBound(step_s=0.02, max_m=rows)}
    )
    return HumanReach(to_reach_params(ps, kind))


@SETTINGS
@given(inputs(), st.integers(0, 1000))
def test_vel_with_a_displacement_table_equals_numpy(c: dict, seed: int) -> None:
    r = _with_table(c["kind"], seed)
    te = np.concatenate([c["te"] * 4.0, [0.0, 0.02, 0.04 - 0.01, 0.1, 0.5]])  # edges, past it
    ends, radius = ref_vel_disp(r, c["y"], te)
    occ = r.vel(c["y"], te)
    _close(occ.ends[:, 0], ends)
    _close(occ.radius[0], radius)
    assert np.all(np.diff(radius, axis=0)[np.diff(te) >= 0] >= 0)  # monotone in time
    _close(r.iso13855(c["y"], te).radius[0], ref_static(r, c["y"], te, r.iso_base, r.iso_speed)[1])


def test_nan_velocity_bound_gives_nan_radius() -> None:
    """A NaN error bound reaches the radius (never a finite, too small set)."""
    r = REACH["full"]
    y = np.zeros((1, 15, 3))
    dv = np.full((1, 15), 0.1)
    dv[0, 3] = np.nan
    occ = r.acc(y, np.zeros_like(y), dv, np.array([0.0]), np.array([0.1]))
    parts = np.flatnonzero((r.skeleton.part_joints == 3).any(axis=1))
    assert parts.size and np.isnan(occ.radius[0, 0, parts]).all()


def test_shapes_the_kernels_cannot_index_raise_input_error() -> None:
    r = REACH["full"]
    t = np.array([0.1])
    with pytest.raises(InputError, match="joint positions"):
        r.vel(np.zeros((1, 14, 3)), t)  # one joint missing
    with pytest.raises(InputError, match="joint positions"):
        r.pos(np.zeros((15, 3)), t)  # no human axis
    y = np.zeros((1, 15, 3))
    with pytest.raises(InputError, match="dv"):
        r.acc(y, y, np.zeros((1, 14)), np.array([0.0]), t)
    with pytest.raises(InputError, match="t_start_s"):
        r.acc(y, y, np.zeros((1, 15)), np.array([0.0, 0.1]), t)
