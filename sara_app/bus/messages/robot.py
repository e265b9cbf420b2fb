"""The robot channel: the controller's measured state, the worker's command with its verified
stop, an operator's re-plan and the controller's heartbeat."""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
from pydantic import Field, model_validator

from sara_app.bus.messages.base import (
    Finite,
    JointVector,
    Mode,
    MsgBase,
    Name,
    NonNeg,
    contract_error,
)


def _same_lengths(**lists: list[float] | None) -> None:
    given = {k: len(v) for k, v in lists.items() if v is not None}
    if len(set(given.values())) > 1:
        raise contract_error("inconsistent_length", f"lengths differ: {given}")


class RobotStateMsg(MsgBase):
    """Measured robot joint state (key ``sara/<cell>/robot/state``); lengths = n_dof."""

    q: JointVector
    q_dot: JointVector
    q_ddot: JointVector | None = None

    @model_validator(mode="after")
    def _lengths(self) -> RobotStateMsg:
        _same_lengths(q=self.q, q_dot=self.q_dot, q_ddot=self.q_ddot)
        return self


COMMAND_VALID_PERIODS = 2
COMMAND_VALID_MIN_S = 0.010
"""A command is valid for this many control periods after its stamp, and at least
``COMMAND_VALID_MIN_S`` (``valid_until_s``): a controller that takes a command that late has
left the commanded path by less than a tracking tolerance (about a_brake * 10 ms^2 / 2, 1.5 mrad
at 30 rad/s^2), while a 500 Hz loop on a busy machine misses two periods now and then."""


def command_validity_s(dt_s: float) -> float:
    """How long after its stamp a command of a cell with control period ``dt_s`` is valid."""
    return max(COMMAND_VALID_PERIODS * dt_s, COMMAND_VALID_MIN_S)


MAX_FAILSAFE_SAMPLES = 512


class RobotCommandMsg(MsgBase):
    """The shielded set point sent to the robot (key ``sara/<cell>/robot/command``), schema
    version 2: the set point ``q``, ``q_dot``, ``q_ddot`` to reach at ``stamp_s + dt`` (the end
    of the cycle's step), ``valid_until_s`` (after it the controller must brake) and the
    verified stop that follows the set point: joint positions ``failsafe_q (F, n)`` at
    ``stamp_s + failsafe_t_s (F,)`` (strictly increasing; the first sample is the set point,
    the last one at rest). Between two samples the robot may move along the straight joint-space
    segment at constant speed (the verified occupancy contains that motion: see
    ``sara_app.robot.occupancy``). Empty when no verified stop exists (JSSA, or not yet)."""

    schema_version: Literal[2] = 2  # type: ignore[assignment]
    q: JointVector
    q_dot: JointVector
    q_ddot: JointVector
    mode: Mode
    valid_until_s: NonNeg
    failsafe_t_s: Annotated[list[Finite], Field(max_length=MAX_FAILSAFE_SAMPLES)] = []
    failsafe_q: Annotated[list[JointVector], Field(max_length=MAX_FAILSAFE_SAMPLES)] = []

    @model_validator(mode="after")
    def _lengths(self) -> RobotCommandMsg:
        _same_lengths(q=self.q, q_dot=self.q_dot, q_ddot=self.q_ddot)
        if len(self.failsafe_t_s) != len(self.failsafe_q):
            raise contract_error(
                "inconsistent_length", "failsafe_t_s and failsafe_q differ in length"
            )
        if any(len(q) != len(self.q) for q in self.failsafe_q):
            raise contract_error("inconsistent_length", "a failsafe sample has another joint count")
        t = self.failsafe_t_s
        if any(b <= a for a, b in zip(t, t[1:])):
            raise contract_error("invalid", "failsafe_t_s must increase strictly")
        if self.valid_until_s < self.stamp_s:
            raise contract_error("invalid", "valid_until_s is before stamp_s")
        return self

    def stop_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """The verified stop as arrays: absolute sample times ``(F,)`` and positions ``(F, n)``;
        without one, the set point at the command's stamp (the robot holds it)."""
        if not self.failsafe_t_s:
            return np.array([self.stamp_s]), np.asarray([self.q], dtype=float)
        return np.asarray(self.failsafe_t_s) + self.stamp_s, np.asarray(self.failsafe_q, float)

    def stop_position(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions and velocities ``(n,)`` at time ``t_s`` along the verified stop, as
        the contract has a controller follow it (:func:`position_on_stop`)."""
        return position_on_stop(*self.stop_arrays(), t_s)


def position_on_stop(
    t_abs_s: np.ndarray, q_stop: np.ndarray, t_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions and velocities ``(n,)`` at ``t_s`` along a stop sampled at ``t_abs_s
    (F,)`` with positions ``q_stop (F, n)``: linear in joint space between the samples on
    schedule, the first sample before it and the last one (at rest) after it (for a command:
    :meth:`RobotCommandMsg.stop_arrays`; kept by who follows it many times)."""
    t, q = t_abs_s, q_stop
    if t_s <= t[0]:
        return q[0].copy(), np.zeros(q.shape[1])
    if t_s >= t[-1]:
        return q[-1].copy(), np.zeros(q.shape[1])
    k = int(np.searchsorted(t, t_s, side="right")) - 1
    slope = (q[k + 1] - q[k]) / (t[k + 1] - t[k])
    return q[k] + slope * (t_s - t[k]), slope


class ReplanMsg(MsgBase):
    """An operator's decision that the robot stands where its controller says (key
    ``sara/<cell>/robot/replan``), after it stopped or was moved away from the worker's plan
    while the same controller ran (a protective stop, a hand guiding; the worker never moves its
    plan there on the controller's word alone, see ``sara_app.runtime.robot_link``). ``q``:
    the joint positions the operator confirms (rad, n_dof). The worker plans from the measured
    state when that state is fresh, at rest and within the tracking tolerance of ``q``, and its
    own plan is at rest; it answers on ``params/ack`` with ``request_id``. ``user`` and
    ``reason`` go to the audit log."""

    request_id: Name
    q: JointVector
    user: Annotated[str, Field(min_length=1, max_length=64)]
    reason: Annotated[str, Field(max_length=500)] = ""


BrakingCause = Literal["controller", "worker", "lost", "delivery"]
"""Why the newest command expired before a newer one came: ``controller``, the controller's own
loop was held up past the command's validity (commands waited in its queue); ``worker``, the
worker's next command was stamped too late (its cycle was held up, or it restarted); ``lost``,
the next command sent never arrived (dropped on the bus); ``delivery``, the next command was
sent in time and arrived too late (the bus or the router was held up)."""


class ControllerStatusMsg(MsgBase):
    """The robot controller's heartbeat, about 1 Hz (key ``sara/<cell>/controller/status``):
    command delivery as the controller saw it since it started. ``commands_lost``: sequence
    numbers of a worker run never received; ``commands_late``: received after their set point's
    time (``stamp_s + dt``); ``commands_expired``: received after ``valid_until_s``;
    ``commands_refused``: not followed (expired and not where the robot stands, a stop that does
    not start at the set point, another joint count);
    ``braking_events``: times the newest command expired and the robot braked on its own;
    ``worker_runs``: worker runs seen (a run's sequence numbers restart at 0); ``braking``: it
    brakes on its own now. Schema version 2 (version 1 had no ``braking_causes`` or
    ``receive_failed``)."""

    schema_version: Literal[2] = 2  # type: ignore[assignment]
    cell: Name
    commands_received: Annotated[int, Field(ge=0)]
    commands_lost: Annotated[int, Field(ge=0)]
    commands_late: Annotated[int, Field(ge=0)]
    commands_expired: Annotated[int, Field(ge=0)]
    commands_refused: Annotated[int, Field(ge=0)]
    braking_events: Annotated[int, Field(ge=0)]
    worker_runs: Annotated[int, Field(ge=0)]
    braking: bool
    braking_causes: dict[BrakingCause, Annotated[int, Field(ge=0)]] = {}
    """Why it braked on its own, per braking event (:data:`BrakingCause`)."""
    receive_failed: bool = False
    """Its wait for commands failed: it reads them at every state due instead, up to a
    control period late (the reference controller; restart it to wait again)."""
