"""The shield's check of a person's arrays as one compiled call
(``sara_app.safety.input_kernels``) against the numpy checks it replaced, on arrays with NaN,
infinities, huge values and negative, NaN or infinite error bounds; and through
``Shield.cycle``: each bad person is a fault naming what is wrong."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.scripted import joints, standing
from sara_app.robot.model import load_robot
from sara_app.robot.trajectory import PathFollower
from sara_app.safety.input_kernels import BAD_BOUND, NON_FINITE, human_values
from sara_app.safety.settings import ShieldSettings
from sara_app.safety.shield import HumanState, Shield


def _oracle(y: np.ndarray, v: np.ndarray, dv: np.ndarray) -> int:
    if not (np.isfinite(y).all() and np.isfinite(v).all()):
        return NON_FINITE
    if not float(dv.min()) >= 0.0:
        return BAD_BOUND
    return 0


def test_the_kernel_is_the_numpy_check() -> None:
    rng = np.random.default_rng(11)
    seen = set()
    for _ in range(5000):
        J = int(rng.choice([9, 15]))
        y, v = rng.normal(size=(J, 3)), rng.normal(size=(J, 3))
        dv = rng.uniform(0, 0.1, J)
        for a in rng.choice(3, size=rng.integers(0, 3)):
            arr = (y, v, dv)[a]
            flat = arr.reshape(-1)
            flat[rng.integers(flat.size)] = rng.choice([np.nan, np.inf, -np.inf, 1e308, -0.5])
        got = human_values(y, v, dv)
        assert got == _oracle(y, v, dv)
        seen.add(got)
    assert seen == {0, NON_FINITE, BAD_BOUND}


@pytest.mark.parametrize(
    ("bad", "words"),
    [("y", "non-finite"), ("v", "non-finite"), ("dv", "error bound"), ("shape", "arrays")],
)
def test_a_bad_person_is_a_fault_of_the_cycle(bad: str, words: str) -> None:
    robot = load_robot("panda")
    reach = HumanReach(to_reach_params(load_param_set("schepp2022_table1"), "full"))
    wps = np.array([[-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8], [1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8]])
    shield = Shield(robot, PathFollower(wps, robot.limits), reach, ShieldSettings())
    y = joints(standing((1.5, 0.0), math.pi))
    v, dv = np.zeros_like(y), np.full(len(y), 0.05)
    if bad == "y":
        y[3, 2] = np.nan
    elif bad == "v":
        v[0, 0] = np.inf
    elif bad == "dv":
        dv[2] = -0.1
    else:
        y = y[:-1]
    res = shield.cycle(1.0, [HumanState("p", y, v, dv, 0.99)], None)
    assert res.mode == "fault" and any(words in f for f in res.faults), res.faults
