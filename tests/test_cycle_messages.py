"""A cycle's verdict and command (sara_app.runtime.messages): the command carries the held
verified stop after its set point, and the stop the worker records for its tracking check
(``sent_stop``) is exactly what the published command says (``stop_arrays``), with a held stop,
without one, and for a fault."""

from __future__ import annotations

import dataclasses

import numpy as np

from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.robot.model import load_robot
from sara_app.robot.trajectory import JointState, PathFollower
from sara_app.runtime.messages import CycleMessages
from sara_app.safety.settings import ShieldSettings
from sara_app.safety.shield import Shield

ROBOT = load_robot("panda")
WPS = np.array([[-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8], [1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8]])


def _same(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> None:
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def test_the_recorded_stop_is_the_commands_own() -> None:
    reach = HumanReach(to_reach_params(load_param_set("schepp2022_table1"), "full"))
    sh = Shield(ROBOT, PathFollower(WPS, ROBOT.limits), reach, ShieldSettings())
    msgs = CycleMessages("c1", ROBOT.n_dof)
    dt, t = sh.settings.dt_s, 1000.0
    res = sh.cycle(t, [], want_distance=False)
    # before any verified cycle is observed: no stop, the set point held
    _, cmd = msgs.verdict_and_command(t, dt, res, {}, (0, 0))
    assert cmd.failsafe_t_s == [] and msgs.sent_stop is not None
    _same(msgs.sent_stop, cmd.stop_arrays())
    for k in range(1, 60):  # verified cycles: the trajectory's stop after the set point
        t += dt
        res = sh.cycle(t, [], want_distance=False)
        msgs.observe(t, res)
        _, cmd = msgs.verdict_and_command(t, dt, res, {}, (k, k))
        assert len(cmd.failsafe_t_s) >= 2
        _same(msgs.sent_stop, cmd.stop_arrays())
    # a fault with a non-finite command: the last command's position, at rest, no stop
    msgs.last = JointState(np.asarray(cmd.q), np.zeros(ROBOT.n_dof), np.zeros(ROBOT.n_dof))
    bad = dataclasses.replace(res, command=JointState(np.full(7, np.nan), np.zeros(7), np.zeros(7)))
    _, cmd = msgs.fault(t + dt, dt, bad, "boom", {}, (99, 99))
    assert cmd.mode == "fault" and cmd.failsafe_t_s == []
    _same(msgs.sent_stop, cmd.stop_arrays())
