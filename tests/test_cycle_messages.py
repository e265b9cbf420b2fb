"""A cycle's verdict and command (sara_app.runtime.messages): the command carries the held
verified stop after its set point; its arrays (``CommandArrays``, what the worker records for
its tracking check and publishes) say exactly what its validated message and its compact record
say, with a held stop, without one, and for a fault; a command the schema would refuse raises
before it is sent, with the contract's reason."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from sara_app.bus.codec import MessageError, decode
from sara_app.bus.compact import CommandArrays, CompactError
from sara_app.bus.keys import robot_command_key
from sara_app.bus.messages import RobotCommandMsg, encode
from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.robot.model import load_robot
from sara_app.robot.trajectory import JointState, PathFollower
from sara_app.runtime.messages import CycleMessages
from sara_app.safety.settings import ShieldSettings
from sara_app.safety.shield import Shield

ROBOT = load_robot("panda")
WPS = np.array([[-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8], [1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8]])
KEY = robot_command_key("c1")


def _same(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray]) -> None:
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def _says_the_same(cmd: CommandArrays) -> None:
    """The arrays, the validated message and both encodings decoded agree exactly."""
    msg = cmd.message()
    _same(cmd.stop_arrays(), msg.stop_arrays())
    for payload in (cmd.record(), encode(msg)):
        got = decode(KEY, payload).msg
        assert got.model_dump() == msg.model_dump()


def _shield() -> Shield:
    reach = HumanReach(to_reach_params(load_param_set("schepp2022_table1"), "full"))
    return Shield(ROBOT, PathFollower(WPS, ROBOT.limits), reach, ShieldSettings())


def test_the_commands_arrays_are_what_it_says() -> None:
    sh = _shield()
    msgs = CycleMessages("c1", ROBOT.n_dof)
    dt, t = sh.settings.dt_s, 1000.0
    res = sh.cycle(t, [], want_distance=False)
    # before any verified cycle is observed: no stop, the set point held
    _, cmd = msgs.verdict_and_command(t, dt, res, {}, (0, 0))
    assert len(cmd.failsafe_t_s) == 0
    _says_the_same(cmd)
    for k in range(1, 60):  # verified cycles: the trajectory's stop after the set point
        t += dt
        res = sh.cycle(t, [], want_distance=False)
        msgs.observe(t, res)
        _, cmd = msgs.verdict_and_command(t, dt, res, {}, (k, k))
        assert len(cmd.failsafe_t_s) >= 2 and cmd.failsafe_t_s[0] == dt
        np.testing.assert_array_equal(cmd.failsafe_q[0], res.command.q)
        _says_the_same(cmd)
    res.command.q[:] = 0.0  # the command keeps arrays of its own
    assert not np.array_equal(cmd.q, res.command.q)
    # a fault with a non-finite command before any command was sent: no command (there is no
    # position to hold; it was all zeros), the verdict says why
    bad = dataclasses.replace(res, command=JointState(np.full(7, np.nan), np.zeros(7), np.zeros(7)))
    verdict, none = msgs.fault(t + dt, dt, bad, "boom", {}, (98, 98))
    assert none is None and verdict.mode == "fault" and verdict.faults == ["boom"]
    # after one: the last command's position, at rest, no stop
    msgs.last = JointState(cmd.q, np.zeros(ROBOT.n_dof), np.zeros(ROBOT.n_dof))
    _, fault = msgs.fault(t + dt, dt, bad, "boom", {}, (99, 99))
    assert fault is not None and fault.mode == "fault" and len(fault.failsafe_t_s) == 0
    np.testing.assert_array_equal(fault.q, cmd.q)
    _says_the_same(fault)


def test_a_fault_with_a_non_finite_held_stop_holds_at_rest() -> None:
    sh = _shield()
    msgs = CycleMessages("c1", ROBOT.n_dof)
    dt, t = sh.settings.dt_s, 1000.0
    for _ in range(20):
        t += dt
        res = sh.cycle(t, [], want_distance=False)
        msgs.observe(t, res)
    assert msgs.held is not None
    msgs.held[1][-1, 3] = np.inf
    with pytest.raises(CompactError, match="non_finite"):
        msgs.verdict_and_command(t, dt, res, {}, (1, 1))
    msgs.last = JointState(res.command.q, np.zeros(7), np.zeros(7))
    _, fault = msgs.fault(t, dt, res, "boom", {}, (2, 2))
    assert fault is not None and msgs.held is None and len(fault.failsafe_t_s) == 0
    np.testing.assert_array_equal(fault.q_dot, np.zeros(7))
    _says_the_same(fault)


def _fields(**change: object) -> dict:
    q = WPS[0]
    fields = {"seq": 5, "stamp_s": 10.0, "mode": "intended", "valid_until_s": 10.02, "q": q,
              "q_dot": np.zeros(7), "q_ddot": np.zeros(7), "failsafe_t_s": [0.002, 0.01, 0.05],
              "failsafe_q": np.stack([q, q + 0.01, q + 0.02])}  # fmt: skip
    return {**fields, **change}


@pytest.mark.parametrize(
    ("change", "reason"),
    [
        ({"q": np.array([0.0, np.nan, 0, 0, 0, 0, 0])}, "non_finite"),
        ({"failsafe_q": np.full((3, 7), np.inf)}, "non_finite"),
        ({"failsafe_t_s": [0.002, np.nan, 0.05]}, "non_finite"),
        ({"failsafe_t_s": np.array([0.002, 0.002, 0.05])}, "invalid"),
        ({"failsafe_t_s": np.array([0.01, 0.002, 0.05])}, "invalid"),
        ({"valid_until_s": 9.0}, "invalid"),
        ({"seq": -1}, "invalid"),
        ({"q_dot": np.zeros(6)}, "inconsistent_length"),
        ({"failsafe_q": np.zeros((2, 7))}, "inconsistent_length"),
        ({"failsafe_t_s": [], "failsafe_q": [], "q_ddot": np.zeros(5)}, "inconsistent_length"),
    ],
)
def test_checked_refuses_what_the_schema_refuses(change: dict, reason: str) -> None:
    """Each command ``checked`` refuses, the message's own validation refuses too, and the
    reason is the contract's (the pydantic path's where it names one)."""
    with pytest.raises(CompactError) as got:
        CommandArrays.build(**_fields(**change))
    assert got.value.reason == reason
    with pytest.raises((ValueError, MessageError)):
        decode(KEY, encode(RobotCommandMsg(**_lists(_fields(**change)))))
    assert CommandArrays.build(**_fields()).message() == RobotCommandMsg(**_lists(_fields()))
    no_stop = _fields(failsafe_t_s=[], failsafe_q=[])
    assert CommandArrays.build(**no_stop).message() == RobotCommandMsg(**_lists(no_stop))


def _lists(fields: dict) -> dict:
    return {k: np.asarray(v).tolist() if k.startswith(("q", "failsafe")) else v
            for k, v in fields.items()}  # fmt: skip


def test_an_unknown_mode_is_refused() -> None:
    with pytest.raises(CompactError, match="mode 'sprint'"):
        CommandArrays.build(**_fields(mode="sprint"))
