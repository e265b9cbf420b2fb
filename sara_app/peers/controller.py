"""The reference robot controller (``sara-app controller``): the contract's controller side in
plain Python, simulating a robot that tracks its set points exactly.

- It follows the valid robot commands (``sara/<cell>/robot/command``, schema version 2) as an
  ideal robot: through each set point at its time ``stamp_s + dt``, on straight joint-space
  segments in between (the commanded trajectory the worker checks its states against).
- Past a set point without a newer command it continues along that command's verified stop, on
  schedule (linear in joint space between the samples, as the contract allows), and rests at
  its end: braking starts at once, whatever the reason (the worker crashed, hangs, or its
  messages are late or lost).
- A late command is followed while it is valid (``valid_until_s``: the robot has left the
  commanded path by less than a tracking tolerance then). Once the newest command expired it
  follows commands again only when their set point is within ``tracking_tol_rad`` of where it
  stands (the worker re-anchors on the measured state); others are counted as refused. The same
  holds for its first command: a controller started while a worker runs follows nothing until
  the worker commands from where the robot stands (found by ``sara-app soak --chaos``: a
  restarted controller took a set point 1.4 rad from its robot).
- A command of another joint count than the robot's (a worker for another robot) is refused and
  counted, never dropped unseen.
- The newest command is the one with the latest ``stamp_s`` (a restarted worker numbers its
  commands from 0 again). Delivery is counted (:class:`Delivery`: received, lost within a
  worker run, late, expired, refused) and published about once a second on
  ``sara/<cell>/controller/status``.
- It wakes when a command arrives and publishes ``robot/state`` on each command taken and, when
  none came, :data:`STATE_GAP_PERIODS` control periods after the last state, stamped with the
  time of the state (:meth:`Controller.run`).

Against a real robot, replace ``_apply`` with the driver's set-point call and publish the
driver's measured state; keep the expiry and braking rules.
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from sara_app.bus import keys
from sara_app.bus.codec import Decoder
from sara_app.bus.messages import (
    BrakingCause,
    ControllerStatusMsg,
    RobotCommandMsg,
    RobotStateMsg,
    position_on_stop,
)
from sara_app.bus.process import SummarisedWarning, process_main
from sara_app.bus.session import Bus
from sara_app.peers.deadline import Deadline
from sara_app.safety.settings import FUTURE_TOLERANCE_S
from sara_app.scenario import Scenario

log = logging.getLogger("sara_app.controller")
MIN_WAIT_S = 20e-6
"""The least time to the next state-due tick. It ticks when a command arrives (taken up at
once) and when a state is due, never on a polling clock (polling every 0.5 ms cost 45 us of CPU
per wake-up on a VM: 40 % of its CPU; a wake-up per period to find that a command had come cost
the next most, and the deadline is now pushed back without one)."""


STATUS_PERIOD_S = 1.0
STATUS_MIN_GAP_S = 0.05
"""A status goes out at once, at most this often, when the robot starts or stops braking on
its own (besides one every :data:`STATUS_PERIOD_S`): the worker plans from where a controller
that says ``braking`` rests at one of its stops' ends (a stalled router's way,
:class:`~sara_app.runtime.robot_link.MeasuredRobot`), and a word up to a second late held the
cell on a tracking fault that long; a stale ``braking`` after the robot follows commands again
is a second's trust the word no longer deserves."""
STATE_GAP_PERIODS = 1.5
"""Without a command, a state at the latest this many control periods after the last one. A
command comes every period, a little late now and then: at one period the state-due deadline
expired about when the command came (0.73 wake-ups and 0.19-0.28 extra states per cycle in a
live cell, each one decoded and checked by the worker and forwarded by the router); half a
period of slack leaves a state per command. The worker faults states older than
``inputs.robot_state_timeout_s`` (0.05 s by default), 25 periods at 500 Hz."""


@dataclass
class Delivery:
    """Counts of the commands as they reached the controller (see
    :class:`~sara_app.bus.messages.ControllerStatusMsg`)."""

    received: int = 0
    lost: int = 0
    late: int = 0
    expired: int = 0
    refused: int = 0
    slowed: int = 0
    """Set points reached after their time: at the joint speed limit, never faster."""
    braking_events: int = 0
    runs: int = 0
    last_seq: int = -1
    causes: dict[BrakingCause, int] = field(default_factory=dict)
    """Braking events per cause (:func:`brake_cause`)."""

    def count(self, cmd: RobotCommandMsg, now: float, dt_s: float) -> None:
        self.received += 1
        if cmd.seq <= self.last_seq or self.runs == 0:  # numbering restarted: a new worker run
            self.runs += 1
        else:
            self.lost += cmd.seq - self.last_seq - 1
        self.last_seq = cmd.seq
        self.late += now > cmd.stamp_s + dt_s
        self.expired += now > cmd.valid_until_s


def brake_cause(braked: RobotCommandMsg, nxt: RobotCommandMsg, tick_gap_s: float) -> BrakingCause:
    """Why ``braked`` (the newest command followed) expired before a newer one came, judged
    when the next newer command ``nxt`` arrives; ``tick_gap_s``: how long the controller's
    loop had not run when it found the command expired (:data:`BrakingCause`)."""
    if tick_gap_s > 0.5 * (braked.valid_until_s - braked.stamp_s):
        return "controller"
    if nxt.seq <= braked.seq:  # a new worker run: the worker restarted
        return "worker"
    if nxt.seq > braked.seq + 1:  # the commands between never came
        return "lost"
    return "worker" if nxt.stamp_s >= braked.valid_until_s else "delivery"


def stop_disagrees(cmd: RobotCommandMsg, dt_s: float) -> str | None:
    """Why ``cmd``'s verified stop does not start where and when its set point is (the contract:
    the first sample is the set point, one control period ``dt_s`` after the stamp), or None.
    Such a command is not followed: a first sample 1 us after the stamp was reached in 1 us,
    one 0.5 rad from the set point was jumped to (58x v_max); and a worker on another period
    than this controller's (another scenario file) is a cell set up wrong (hostile-user probe
    2026-12-01)."""
    if not cmd.failsafe_t_s:
        return None
    if abs(cmd.failsafe_t_s[0] - dt_s) > 1e-9:
        t0 = cmd.failsafe_t_s[0]
        return f"its stop starts {t0:g} s after its stamp, not one period ({dt_s:g} s)"
    if cmd.failsafe_q[0] != cmd.q:
        return "its stop does not start at its set point"
    return None


class Controller:
    """One cell's reference controller. ``tick(now)`` is one control period."""

    def __init__(self, cell: str, scenario: Scenario, bus: Bus) -> None:
        self.cell = keys.check_name("cell", cell)
        self.dt_s = scenario.shield.dt_s
        self.state_gap_s = STATE_GAP_PERIODS * self.dt_s
        """Without a command, a state this long after the last one (:data:`STATE_GAP_PERIODS`)."""
        self.tol_rad = scenario.shield.tracking_tol_rad
        self.v_max = np.asarray(scenario.robot.load(margin=False).limits.v_max, dtype=float)
        """The robot's joint speed limits (rad/s): no set point is reached faster."""
        self.q = np.asarray(scenario.task.waypoints_rad[0], dtype=float)
        self.v = np.zeros_like(self.q)
        self.command: RobotCommandMsg | None = None
        self._stop = (np.zeros(0), np.zeros((0, len(self.q))))
        """The followed command's verified stop as arrays (:meth:`RobotCommandMsg.stop_arrays`)."""
        self.braking = False  # on its own, along the expired command's stop
        self.points: list[tuple[float, np.ndarray]] = []
        """Where the robot is to be when: ``(t, q)``, the first where it stood, then the set
        points not yet reached."""
        self.delivery = Delivery()
        self._expired_log = SummarisedWarning(log, "commands expired")
        self._disagree_log = SummarisedWarning(log, "commands refused")
        self._slowed_log = SummarisedWarning(log, "set points reached late")
        self._tick_s = -np.inf
        self._applied_s = -np.inf
        """When the robot's set point was last applied (the speed limit counts from it)."""
        self._braked: tuple[RobotCommandMsg, float] | None = None
        """The command that expired and the controller's loop gap then, until the next newer
        command tells why (:func:`brake_cause`)."""
        self.published_s = -1.0
        self.status_s = -np.inf
        self.said_braking = False
        """``braking`` as the last status said it."""
        self.stop_event = threading.Event()
        self.receiver_ended = False
        """The receiving thread of :meth:`run` ended before the stop; :meth:`_watch` reads."""
        # a stamp from the future would hold back every later command: refused (out_of_range)
        # beyond one control period (a worker catching up after a late cycle stamps its
        # commands a period apart, up to a period ahead of the clock: CellWorker.step)
        self.decoder = Decoder(max_future_s=FUTURE_TOLERANCE_S + self.dt_s)
        self.sub = bus.subscribe(keys.robot_command_key(self.cell), self.decoder, capacity=64)
        self.pub = bus.publisher(keys.robot_state_key(self.cell))
        self.pub_status = bus.publisher(keys.controller_status_key(self.cell))

    def _received(self, now: float, given: list[RobotCommandMsg] | None) -> list[RobotCommandMsg]:
        """The commands that came since the last tick (``given``, else those the subscription
        decoded), counted, in order of their stamps (every set point counts: the robot passes
        through each)."""
        if given is None:
            given = [d.msg for d in self.sub.drain().messages if isinstance(d.msg, RobotCommandMsg)]
        n = len(self.q)
        got = [m for m in given if len(m.q) == n]
        if len(got) < len(given):  # a worker for another robot: refused, never dropped unseen
            self.delivery.refused += len(given) - len(got)
            joints = sorted({len(m.q) for m in given} - {n})
            self._disagree_log(f"{joints} joints where this robot has {n}")
        for cmd in got:
            self.delivery.count(cmd, now, self.dt_s)
        got.sort(key=lambda m: m.stamp_s)
        self._why_braked(got)
        return got

    def _why_braked(self, got: list[RobotCommandMsg]) -> None:
        """Count the cause of the last braking once a newer command than the expired one is
        among ``got`` (sorted by stamp)."""
        if self._braked is None:
            return
        braked, gap_s = self._braked
        nxt = next((m for m in got if m.stamp_s > braked.stamp_s), None)
        if nxt is not None:
            cause = brake_cause(braked, nxt, gap_s)
            self.delivery.causes[cause] = self.delivery.causes.get(cause, 0) + 1
            self._braked = None

    def tick(self, now: float, commands: list[RobotCommandMsg] | None = None) -> None:
        """One poll at time ``now``: the commands received (``commands``: these instead of the
        subscription's, as a driver that receives them otherwise hands them over), then the
        robot's set point and state."""
        since_s = now - self.status_s
        if since_s >= STATUS_PERIOD_S or (
            self.braking != self.said_braking and since_s >= STATUS_MIN_GAP_S
        ):
            self.publish_status(now)
        gap_s, self._tick_s = now - self._tick_s, now
        got = False
        received = self._received(now, commands)
        for cmd in received:
            if self._acceptable(cmd, now):
                self._follow(cmd, now)
                got = True
        if not got and now - self.published_s < self.state_gap_s:
            return  # no command: a state every STATE_GAP_PERIODS periods (the contract's least)
        if self.command is None or not self.points:
            self.publish(now)
            return
        if now <= self.points[-1][0]:
            self._apply(*self._on_points(now), now)
        else:  # past the set point without a newer command: on its verified stop, on schedule
            if now > self.command.valid_until_s and not self.braking:
                self.delivery.braking_events += 1
                self._expired_log("braking along the last verified stop")
                self.braking = True
                self._braked = (self.command, gap_s)
                self._why_braked(received)  # newer ones that came expired this tick
            self._apply(*position_on_stop(*self._stop, now), now)
        self.publish(now)

    def _follow(self, cmd: RobotCommandMsg, now: float) -> None:
        """Add ``cmd``'s set point (reached at stamp + dt) to the set points ahead; the robot
        passes through each on schedule (the commanded trajectory the worker checks)."""
        if self.braking or not self.points:
            self.points = [(now, self.q.copy())]  # from where it stands
        elif now >= self.points[-1][0] and self.command is not None:
            # past the last set point the robot is on that command's stop, not at the set
            # point (taking the set point made it jump back by speed x delay: a tracking fault
            # whenever a command took more than about 2 ms to arrive)
            self.points = [(now, position_on_stop(*self._stop, now)[0])]
        else:
            q_now, _ = self._on_points(now)
            ahead = [p for p in self.points if p[0] > now]
            self.points = [(now, q_now), *ahead]
        t_from, q_from = self.points[-1]
        q_to = np.asarray(cmd.q, dtype=float)
        # never faster than the robot can: a command that came after its set point's time (or
        # after braking) was reached in 1 us, up to 3.98x v_max over 0.5 ms in a live cell
        # (robot channel probe, 2026-12-01); its stop stays on the verified schedule, which the
        # robot catches up with at most v_max (_apply)
        t_due = cmd.stamp_s + self.dt_s
        t_reached = t_from + float(np.max(np.abs(q_to - q_from) / self.v_max))
        t_to = max(t_due, t_reached, t_from + 1e-6)
        # late by the speed limit only (every cell's first command, where the robot stands,
        # was logged as reached late)
        late_s = t_to - t_due if t_reached > max(t_due, t_from + 1e-6) else 0.0
        self.points.append((t_to, q_to))
        self.command, self.braking = cmd, False
        self._stop = cmd.stop_arrays()  # followed many times: its arrays once
        if late_s > 1e-6:
            self.delivery.slowed += 1
            self._slowed_log(f"set point {late_s * 1e3:.3f} ms after its time (joint speed limit)")

    def _acceptable(self, cmd: RobotCommandMsg, now: float) -> bool:
        """A command is followed while valid; before the first one and once the robot brakes on
        its own (the newest command expired), only one whose set point is where the robot
        stands (the worker re-anchored on the measured state)."""
        if self.command is not None and cmd.stamp_s <= self.command.stamp_s:
            return False  # not newer than the one followed (by time: seq restarts per run)
        why = stop_disagrees(cmd, self.dt_s)
        if why is not None:
            self._disagree_log(why)
            self.delivery.refused += 1
            return False
        if self.command is not None and not self.braking and now <= cmd.valid_until_s:
            return True
        # braking on its own, or no command followed yet (a controller that just started: the
        # worker's command was verified from where the worker believed the robot to be)
        if float(np.max(np.abs(np.asarray(cmd.q) - self.q))) <= self.tol_rad:
            return True
        self.delivery.refused += 1
        return False

    def _on_points(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity at ``t_s`` on the straight segments through the set points
        ahead (at the last one, at rest, from its time on)."""
        pts = self.points
        if t_s >= pts[-1][0]:
            return pts[-1][1], np.zeros_like(pts[-1][1])
        k = max(i for i, (t, _) in enumerate(pts) if t <= t_s) if t_s >= pts[0][0] else 0
        (t0, q0), (t1, q1) = pts[k], pts[k + 1]
        slope = (q1 - q0) / (t1 - t0)
        return q0 + slope * (max(t_s, t0) - t0), slope

    def _apply(self, q: np.ndarray, v: np.ndarray, now: float) -> None:
        """The robot's set point at ``now`` (an ideal robot: reached at once), but never faster
        than ``v_max``: a robot behind the verified schedule (a set point reached late) moves
        straight towards the scheduled position at the joint speed limit (along the path where
        the path is straight) and is back on the schedule once the schedule slows enough (a
        verified stop always comes to rest). Shifting the stop by the delay instead left the
        robot off its verified stop for the whole braking (CI of stop 52: 0.5 mrad off a killed
        worker's stop)."""
        elapsed_s = now - self._applied_s
        if elapsed_s <= 0.0:  # no time passed: the robot has not moved
            self._applied_s = now
            return
        step = q - self.q
        over = float(np.max(np.abs(step) / (self.v_max * elapsed_s)))
        if over > 1.0:
            q, v = self.q + step / over, step / (over * elapsed_s)
        self.q, self.v, self._applied_s = q, v, now

    def publish(self, now: float) -> None:
        self.published_s = now
        self.pub.put(
            RobotStateMsg(
                seq=self.pub.next_seq(), stamp_s=now, q=self.q.tolist(), q_dot=self.v.tolist()
            )
        )

    def publish_status(self, now: float) -> None:
        self.status_s, self.said_braking = now, self.braking
        d = self.delivery
        self.pub_status.put(
            ControllerStatusMsg(
                seq=self.pub_status.next_seq(),
                stamp_s=now,
                cell=self.cell,
                commands_received=d.received,
                commands_lost=d.lost,
                commands_late=d.late,
                commands_expired=d.expired,
                commands_refused=d.refused,
                braking_events=d.braking_events,
                worker_runs=d.runs,
                braking=self.braking,
                braking_causes=dict(d.causes),
                receive_failed=self.receiver_ended,
            )
        )

    def run(self, duration_s: float | None = None) -> None:
        """Take each command the moment it arrives (a receiving thread that sleeps in zenoh's
        channel) and publish a state when a control period passed without one (a thread that
        sleeps on a :class:`~sara_app.peers.deadline.Deadline` pushed back at every state);
        this thread waits for the stop (``stop_event``, or ``duration_s``)."""
        self._lock = threading.Lock()
        self._due = Deadline()
        self._locked_tick([])
        threads = [threading.Thread(target=f, name=f"controller-{f.__name__.strip('_')}",
                                    daemon=True) for f in (self._receive, self._watch)]  # fmt: skip
        for t in threads:
            t.start()
        try:
            self.stop_event.wait(duration_s)
        finally:
            self.stop_event.set()
            self.sub.close()  # ends the receiving thread's wait
            self._due.close()
            for t in threads:
                t.join(5.0)
            self._due.release()

    def _locked_tick(self, commands: list[RobotCommandMsg] | None) -> None:
        """:meth:`tick` now, under the lock (the time read inside it: the two threads' ticks
        and states stay in time order), then the deadline moved to a period after the last
        state; an error is logged and the robot keeps braking (never the end of the loop)."""
        with self._lock:
            try:
                self.tick(time.time(), commands)
            except Exception:  # noqa: BLE001 - keep braking rather than die
                log.exception("controller tick failed")
            self._due.arm(max(self.published_s + self.state_gap_s - time.time(), MIN_WAIT_S))

    def _receive(self) -> None:
        """Tick on each batch of commands received. Should the wait end other than by the
        stop (an error from zenoh's channel, or a decoding error), the deadline's thread takes
        over the reading (:meth:`_watch`): the commands are then taken at the next state due,
        never left unread (a receiving thread that ended silently once left a controller
        braking for good while the worker commanded it)."""
        try:
            while not self.stop_event.is_set():
                got = self.sub.receive()
                if got is None:
                    break
                cmds = [d.msg for d in got.messages if isinstance(d.msg, RobotCommandMsg)]
                self._locked_tick(cmds)
        except Exception:  # noqa: BLE001 - the deadline's thread reads on
            log.exception("controller: waiting for commands failed")
        if not self.stop_event.is_set():
            log.error(
                "controller: the command subscription's wait ended; reading the commands at"
                " every state due instead (about one control period late)"
            )
            self.receiver_ended = True
            self._locked_tick(None)  # what came meanwhile, and the deadline re-armed

    def _watch(self) -> None:
        while self._due.wait() and not self.stop_event.is_set():
            self._locked_tick(None if self.receiver_ended else [])


def main(argv: list[str] | None = None) -> int:
    # one I/O thread: its only subscription (commands) is a ring, never back-pressured
    return process_main(
        "controller", "the reference robot controller", Controller, argv, one_io_thread=True
    )


if __name__ == "__main__":
    sys.exit(main())
