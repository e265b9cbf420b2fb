"""Widened sets contain motion measured less precisely than the parameter set assumes, and the
legs an upper-body source does not measure: the same synthetic motions as ``test_reach`` (each
model's own bounds), measured with noise up to delta_y + extra, or with the leg joints replaced
by the pelvis; every future joint, grown by its part's half thickness, lies in its capsule grown
by the widening. Zero misses allowed."""

from __future__ import annotations

import numpy as np
import pytest
from test_reach import (
    T_END,
    T_START,
    _check_contained,
    _on_sphere,
    _pose,
    _rand_ball,
    _reach,
    _simulate,
    pos_future,
)

from sara_app.human.anatomy import UNMEASURED_LEG_REACH_M
from sara_app.human.reach import MODELS, part_capsules
from sara_app.human.skeleton import UPPER_JOINTS, full_body
from sara_app.human.widening import (
    capsule_widening,
    per_capsule,
    widening,
)

EXTRA_M = 0.03


def _measured(rng, y_true: np.ndarray, delta_y: float, legs: bool) -> np.ndarray:
    """A measurement with noise up to ``delta_y`` (the worst case: on the sphere), legs at the
    pelvis when ``legs`` is False."""
    y = y_true + _on_sphere(rng, y_true.shape, np.full(y_true.shape[:2], delta_y))
    if legs:
        return y
    return np.stack([full_body(h[: len(UPPER_JOINTS)], None)[0] for h in y])


def _widened(reach, model: str, occ, extra_m: float, legs: bool):
    ext = capsule_widening(reach, extra_m, legs)[model]
    return occ.ends, occ.radius + ext


@pytest.mark.parametrize(("extra_m", "legs"), [(EXTRA_M, True), (0.0, False), (EXTRA_M, False)])
@pytest.mark.parametrize("seed", range(3))
def test_vel_and_iso_contain_the_person(extra_m: float, legs: bool, seed: int) -> None:
    rng = np.random.default_rng(300 + seed)
    reach = _reach("full")
    p = reach.params
    y_true = _pose(rng, "full", 16)
    y_meas = _measured(rng, y_true, p.delta_y_m + extra_m, legs)
    J = y_true.shape[1]
    v_lim = {"vel": p.v_max_mps, "iso13855": np.full_like(p.v_max_mps, p.iso_v_max_mps)}
    for m in ("vel", "iso13855"):
        ends, radius = _widened(reach, m, reach.model(m, y_meas, None, None, T_START, T_END),
                                extra_m, legs)  # fmt: skip
        v0 = _rand_ball(rng, y_true.shape, np.broadcast_to(v_lim[m], y_true.shape[:2]))
        for k in range(len(T_START)):
            times = np.linspace(0, T_END[k] + p.delay_s, 60)
            paths = _simulate(rng, y_true, v0, np.full(J, 300.0), v_lim[m], times)
            sel = times >= T_START[k] + p.delay_s
            assert _check_contained(reach, m, ends, radius, paths[sel], k) <= 1e-12, m


@pytest.mark.parametrize("seed", range(3))
def test_acc_contains_the_person_with_a_larger_position_error(seed: int) -> None:
    rng = np.random.default_rng(400 + seed)
    reach = _reach("full")
    p = reach.params
    y_true = _pose(rng, "full", 16)
    v_true = _rand_ball(rng, y_true.shape, np.full(y_true.shape[:2], 3.0))
    dv = np.full(y_true.shape[:2], 0.3)
    y_meas = _measured(rng, y_true, p.delta_y_m + EXTRA_M, True)
    v_meas = v_true + _on_sphere(rng, y_true.shape, dv)
    occ = reach.model("acc", y_meas, v_meas, dv, T_START, T_END)
    ends, radius = _widened(reach, "acc", occ, EXTRA_M, True)
    for k in range(len(T_START)):
        times = np.linspace(0, T_END[k] + p.delay_s, 80)
        paths = _simulate(rng, y_true, v_true, p.a_max_mps2, None, times)
        sel = times >= T_START[k] + p.delay_s
        assert _check_contained(reach, "acc", ends, radius, paths[sel], k) <= 1e-12


@pytest.mark.parametrize(("extra_m", "legs"), [(EXTRA_M, True), (0.0, False), (EXTRA_M, False)])
def test_pos_contains_rigid_limbs(extra_m: float, legs: bool) -> None:
    rng = np.random.default_rng(500)
    reach = _reach("full")
    p = reach.params
    H = 32
    y_true = _pose(rng, "full", H)
    y_meas = _measured(rng, y_true, p.delta_y_m + extra_m, legs)
    ends, radius = _widened(reach, "pos", reach.model("pos", y_meas, None, None, T_START, T_END),
                            extra_m, legs)  # fmt: skip
    k = len(T_START) - 1
    for _ in range(20):
        fut = pos_future(rng, reach, y_true, T_END[k] + p.delay_s)
        assert _check_contained(reach, "pos", ends, radius, fut[None], k) <= 1e-12


def test_the_leg_bound_covers_the_test_poses_and_nothing_else_grows() -> None:
    """The poses above keep their legs within the named leg reach of the pelvis (else the
    tests would prove nothing about it); a full-body skeleton within delta_y widens nothing;
    the arm model's arm capsules are not trusted under a larger error."""
    rng = np.random.default_rng(0)
    reach = _reach("full")
    sk = reach.skeleton
    y = _pose(rng, "full", 64)
    legs = [sk.joint_index(j) for j in sk.joints if j not in UPPER_JOINTS]
    pelvis = sk.joint_index("pelvis")
    reach_m = np.linalg.norm(y[:, legs] - y[:, pelvis : pelvis + 1], axis=-1).max(axis=0)
    named = np.array([UNMEASURED_LEG_REACH_M[sk.joints[j].split("_")[1]] for j in legs])
    assert (reach_m < named).all() and (reach_m > 0.6 * named).all()
    assert widening(reach, 0.0, legs_measured=True) is None
    w = widening(reach, EXTRA_M, legs_measured=True)
    assert w is not None and w.shape == (len(MODELS), sk.n_parts)
    arm = w[MODELS.index("arm")]
    assert np.isinf(arm[[sk.part_index("l_hand"), sk.part_index("r_upper_arm")]]).all()
    assert np.isfinite(w[MODELS.index("vel")]).all()


def test_per_part_and_per_capsule_agree() -> None:
    """The per-part rows the PFL kernels add are the capsule values they stand for, and the
    capsules the SSM check grows get them back (every capsule a part stands for)."""
    reach = _reach("full")
    for legs in (True, False):
        caps = capsule_widening(reach, EXTRA_M, legs)
        w = widening(reach, EXTRA_M, legs)
        assert w is not None
        for i, m in enumerate(MODELS):
            pm = part_capsules(reach, m)
            np.testing.assert_array_equal(w[i], caps[m][pm])
            back = per_capsule(w[i], pm, len(caps[m]))
            np.testing.assert_array_equal(back[np.unique(pm)], caps[m][np.unique(pm)])
