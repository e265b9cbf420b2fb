"""The reported separation in one compiled call (``sara_app.safety.distance_kernels`` behind
``Shield.min_distance``) against its oracle: pinocchio's link capsules at the configuration and
``body_distance`` per person, the minimum over people; NaN in, NaN out; no people, inf; inputs
of the wrong shape are refused before the kernel (it indexes without bounds checks)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sara_app.errors import InputError
from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.scripted import joints, standing
from sara_app.robot.model import load_robot
from sara_app.robot.trajectory import PathFollower
from sara_app.safety.settings import ShieldSettings
from sara_app.safety.shield import Shield
from sara_app.safety.ssm import body_distance

WPS = np.array([[-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8], [1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8]])


def _shield(robot: str = "panda", tracks: str = "full") -> Shield:
    model = load_robot(robot)
    reach = HumanReach(to_reach_params(load_param_set("bench_work"), tracks))
    mid = 0.5 * (model.limits.q_min + model.limits.q_max)
    wps = np.stack([mid, mid + 0.1])
    return Shield(model, PathFollower(wps, model.limits), reach, ShieldSettings())


def _oracle(sh: Shield, q: np.ndarray, ys: list[np.ndarray]) -> float:
    ends, radius = sh.robot.link_capsules(q)
    sk = sh.reach.skeleton
    half = sh.reach.params.half_thickness_m
    return min(body_distance(y, sk.part_joints, half, ends, radius) for y in ys)


def _people(sh: Shield, rng: np.random.Generator, k: int) -> list[np.ndarray]:
    """``k`` people standing 0.2-1.5 m from the base, limbs jittered, some overlapping links."""
    J = sh.reach.skeleton.n_joints
    out = []
    for _ in range(k):
        r, a = rng.uniform(0.2, 1.5), rng.uniform(-math.pi, math.pi)
        y = joints(standing((r * math.cos(a), r * math.sin(a)), a + math.pi))
        y = y[:J] if len(y) >= J else y
        out.append(y + rng.normal(0.0, 0.1, y.shape) + [0.0, 0.0, rng.uniform(-0.5, 0.5)])
    return out


@pytest.mark.parametrize(("robot", "tracks"), [("panda", "full"), ("ur10e", "upper")])
def test_equals_pinocchio_and_body_distance(robot: str, tracks: str) -> None:
    sh = _shield(robot, tracks)
    rng = np.random.default_rng(7)
    lim = sh.robot.limits
    signs = set()
    for _ in range(200):
        q = rng.uniform(lim.q_min, lim.q_max)
        ys = _people(sh, rng, int(rng.integers(1, 5)))
        got, want = sh.min_distance(q, ys), _oracle(sh, q, ys)
        assert abs(got - want) <= 1e-12, (got, want)
        signs.add(got > 0.0)
    assert signs == {True, False}  # both apart and overlapping were drawn


def test_no_people_is_inf_and_nan_is_nan() -> None:
    sh = _shield()
    q = WPS[0]
    ys = _people(sh, np.random.default_rng(3), 2)
    assert sh.min_distance(q, []) == math.inf
    bad = ys[1].copy()
    bad[4, 2] = np.nan
    assert math.isnan(sh.min_distance(q, [ys[0], bad]))
    q_bad = q.copy()
    q_bad[2] = np.nan
    assert math.isnan(sh.min_distance(q_bad, ys))


def test_other_dtypes_and_layouts_give_the_same_distance() -> None:
    sh = _shield()
    ys = _people(sh, np.random.default_rng(5), 1)
    want = sh.min_distance(WPS[0], ys)
    assert sh.min_distance(WPS[0].tolist(), [ys[0].tolist()]) == want  # type: ignore[list-item]
    assert sh.min_distance(WPS[0], [np.asfortranarray(ys[0])]) == want
    assert sh.min_distance(WPS[0], [ys[0].astype(np.float32)]) == pytest.approx(want, abs=1e-6)


def test_wrong_shapes_are_refused() -> None:
    sh = _shield()
    y = _people(sh, np.random.default_rng(1), 1)[0]
    with pytest.raises(InputError, match=r"expected \(7,\)"):
        sh.min_distance(np.zeros(6), [y])
    with pytest.raises(InputError, match="joints"):
        sh.min_distance(WPS[0], [y[:-1]])
    with pytest.raises(InputError, match="joints"):
        sh.min_distance(WPS[0], [y[:, :2]])
