"""What one control cycle publishes: its verdict and its robot command, with the verified stop
the controller brakes along when commands stop (the contract's robot command, version 2).

The stop is the one the follower holds: the failsafe of the last verified shielded trajectory
(``CycleResult.verified``). A verified cycle's command carries that trajectory's samples after
its step; a braking cycle's command, the set point (a point of the held stop) and the held
stop's later samples. Between two samples the straight joint-space segment at constant speed is
inside the verified occupancy (``sara_app.robot.occupancy``: any motion between two samples
within the interval's speed bound is; the segment's speed is the mean speed, below it). JSSA
verifies no stop: its commands carry none.
"""

from __future__ import annotations

import math
from typing import Any, Protocol, cast

import numpy as np

from sara_app.bus.compact import CommandArrays, CompactError
from sara_app.bus.messages import (
    JointFlagMsg,
    TrackingNowMsg,
    VerdictMsg,
    ViolationMsg,
)
from sara_app.bus.messages.robot import command_validity_s
from sara_app.human.conformance import Violation
from sara_app.human.intake import TrackingNow
from sara_app.kernel_types import as_f8, entry
from sara_app.robot.trajectory import JointState
from sara_app.runtime.command_kernels import FINITE, command_body
from sara_app.safety.settings import mode_facts
from sara_app.safety.shield import CycleResult

_NO_TIMES = np.empty(0)
_NO_TIMES.flags.writeable = False
_COMMAND_BODY = entry(command_body)
"""Without numba's dispatcher: :meth:`CycleMessages._command` checks the shapes and dtypes."""


class CycleMessages:
    """Builds each cycle's verdict and command; keeps the held verified stop."""

    def __init__(self, cell: str, n_dof: int) -> None:
        self.cell = cell
        self.n_dof = n_dof
        self.held: tuple[np.ndarray, np.ndarray] | None = None
        """The held stop: absolute sample times ``(K+1,)`` s and positions ``(K+1, n)``."""
        self.last: JointState | None = None
        self._no_stop = np.empty((0, n_dof))

    def observe(self, now: float, res: CycleResult, holds_failsafe: bool = True) -> None:
        """Track the stop the follower holds after this cycle (none in a mode that holds no
        verified failsafe: :attr:`Shield.holds_failsafe <sara_app.safety.shield.Shield>`)."""
        if not holds_failsafe:
            self.held = None
        elif res.verified and res.trajectory is not None:
            traj = res.trajectory
            self.held = (as_f8(now + traj.times), np.array(traj.q, dtype=np.float64))

    def verdict_and_command(
        self,
        now: float,
        dt: float,
        res: CycleResult,
        dropped: dict[str, int],
        seqs: tuple[int, int],
        people: People | None = None,
        blocking: list[str] | None = None,
    ) -> tuple[VerdictMsg, CommandArrays]:
        """The cycle's verdict and command, numbered ``seqs``; raises when a value cannot be
        sent (non-finite: :class:`~sara_app.bus.compact.CompactError`). ``people``: the
        tracking flags and violations to report."""
        dist = res.min_distance_m
        verdict = VerdictMsg(
            seq=seqs[0],
            stamp_s=now,
            cell=self.cell,
            safety_mode=cast(Any, res.safety_mode),
            mode=cast(Any, res.mode),
            results=res.model_free,
            skeleton_age_s=res.ages_s,
            min_distance_m=dist if dist is not None and math.isfinite(dist) else None,
            cycle_time_us=res.cycle_time_us,
            faults=[f[:300] for f in res.faults[:8]],
            dropped=dropped,
            intervened=res.intervened,
            speed_scale=res.speed_scale if mode_facts(res.safety_mode).scales_speed else None,
            tracking=cast(Any, {} if people is None else people.tracking()),
            tracking_now={} if people is None else tracking_now_msgs(people.tracking_now()),
            violations=[] if people is None else violation_msgs(people.violations()),
            blocking=blocking or [],
        )
        return verdict, self._command(now, dt, res.command, res.mode, seqs[1])

    def _command(self, now: float, dt: float, c: JointState, mode: str, seq: int) -> CommandArrays:
        """The command of set point ``c`` (reached at ``now + dt``) with the held stop's later
        samples after it (none without a held stop), checked against the schema's rules
        (raises :class:`~sara_app.bus.compact.CompactError`); its arrays are its own."""
        n = self.n_dof
        q, v, a = as_f8(c.q), as_f8(c.v), as_f8(c.a)
        times, qs = self.held if self.held is not None else (_NO_TIMES, self._no_stop)
        if (q.shape, v.shape, a.shape, qs.shape) != ((n,), (n,), (n,), (times.shape[0], n)):
            raise CompactError(
                "inconsistent_length",
                f"set point {q.shape}, {v.shape}, {a.shape} and held stop {times.shape}, "
                f"{qs.shape}; expected ({n},) each and (K,), (K, {n})",
            )
        status, body = _COMMAND_BODY(now, dt, q, v, a, self.held is not None, times, qs)
        if status:
            why = "a joint value or stop sample is not finite" if status == FINITE else (
                "the held stop's times do not increase strictly")  # fmt: skip
            raise CompactError("non_finite" if status == FINITE else "invalid", why)
        valid_until_s = now + command_validity_s(dt)
        command = CommandArrays(seq, now, mode, valid_until_s, n, body)
        command.check_fields()
        return command

    def fault(
        self,
        now: float,
        dt: float,
        res: CycleResult,
        why: str,
        dropped: dict[str, int],
        seqs: tuple[int, int],
    ) -> tuple[VerdictMsg, CommandArrays | None]:
        """A fault verdict that names ``why`` and the command of the held failsafe: the
        cycle's command when it and the held stop are finite (the shield moved the robot
        there), else the last one sent, at rest (and then no stop: the robot holds); None
        when none was sent yet (this worker never commanded the robot: a command at an
        invented position, all zeros before 2026-11-30, could move it there; without one
        the controller brakes or stays as the contract says)."""
        command: CommandArrays | None = None
        try:
            command = self._command(now, dt, res.command, "fault", seqs[1])
        except CompactError:  # not finite (the command or the held stop): hold, at rest
            self.held = None
            if self.last is not None:
                zero = np.zeros(self.n_dof)
                at_rest = JointState(self.last.q, zero, zero)
                command = self._command(now, dt, at_rest, "fault", seqs[1])
        verdict = VerdictMsg(
            seq=seqs[0],
            stamp_s=now,
            cell=self.cell,
            safety_mode=cast(Any, res.safety_mode),
            mode="fault",
            cycle_time_us=0.0,
            faults=[why[:300]],
            dropped=dropped,
            intervened=True,
        )
        return verdict, command


class People(Protocol):
    """What a verdict reports of the people (``sara_app.runtime.presence.Presence``)."""

    def tracking(self) -> dict[str, dict[str, int]]: ...

    def tracking_now(self) -> dict[str, TrackingNow]: ...

    def violations(self) -> list[tuple[str, Violation]]: ...


def tracking_now_msgs(found: dict[str, TrackingNow]) -> dict[str, TrackingNowMsg]:
    def flag(f: tuple[str, str, float]) -> JointFlagMsg:
        return JointFlagMsg(joint=f[0], flag=cast(Any, f[1]), stamp_s=f[2])

    return {
        h: TrackingNowMsg(held=[flag(f) for f in n.held[:32]],
                          last_flag=None if n.last_flag is None else flag(n.last_flag))
        for h, n in list(found.items())[:64]
    }  # fmt: skip


def violation_msgs(found: list[tuple[str, Violation]]) -> list[ViolationMsg]:
    return [
        ViolationMsg(human_id=h, joint=v.joint, quantity=cast(Any, v.quantity),
                     value=v.value, bound=v.bound, stamp_s=v.t_s)
        for h, v in found[:64]
    ]  # fmt: skip
