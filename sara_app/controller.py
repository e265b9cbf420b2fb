"""The reference robot controller (``sara-app controller``): the contract's controller side in
plain Python, simulating a robot that tracks its set points exactly.

- It follows the newest valid robot command (``sara/<cell>/robot/command``, schema version 2)
  as an ideal robot: from where it stands to the set point on the straight joint-space segment,
  reaching it at ``stamp_s + dt``.
- Past a set point without a newer command it continues along that command's verified stop, on
  schedule (linear in joint space between the samples, as the contract allows), and rests at
  its end: braking starts at once, whatever the reason (the worker crashed, hangs, or its
  messages are late or lost).
- A late command is followed while it is valid (``valid_until_s``: the robot has left the
  commanded path by less than a tracking tolerance then). Once the newest command expired it
  follows commands again only when their set point is within ``tracking_tol_rad`` of where it
  stands (the worker re-anchors on the measured state); others are counted as refused.
- It polls for commands and publishes ``robot/state`` every half control period, stamped with
  the time of the state.

Against a real robot, replace ``_apply`` with the driver's set-point call and publish the
driver's measured state; keep the expiry and braking rules.
"""

from __future__ import annotations

import logging
import sys
import threading
import time

import numpy as np

from sara_app.bus import keys
from sara_app.bus.codec import Decoder
from sara_app.bus.messages import RobotCommandMsg, RobotStateMsg
from sara_app.bus.process import process_main
from sara_app.bus.session import Bus
from sara_app.scenario import Scenario

log = logging.getLogger("sara_app.controller")


def stop_position(cmd: RobotCommandMsg, t_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions and velocities at time ``t_s`` along ``cmd``'s verified stop: linear in
    joint space between its samples on schedule, the set point before the first and the last
    sample (at rest) after it; ``(n,)`` each."""
    if not cmd.failsafe_t_s:
        return np.asarray(cmd.q, dtype=float), np.zeros(len(cmd.q))
    t = np.asarray(cmd.failsafe_t_s) + cmd.stamp_s
    q = np.asarray(cmd.failsafe_q, dtype=float)
    if t_s <= t[0]:
        return q[0].copy(), np.zeros(q.shape[1])
    if t_s >= t[-1]:
        return q[-1].copy(), np.zeros(q.shape[1])
    k = int(np.searchsorted(t, t_s, side="right")) - 1
    slope = (q[k + 1] - q[k]) / (t[k + 1] - t[k])
    return q[k] + slope * (t_s - t[k]), slope


class Controller:
    """One cell's reference controller. ``tick(now)`` is one control period."""

    def __init__(self, cell: str, scenario: Scenario, bus: Bus) -> None:
        self.cell = keys.check_name("cell", cell)
        self.dt_s = scenario.shield.dt_s
        self.tol_rad = scenario.shield.tracking_tol_rad
        self.q = np.asarray(scenario.task.waypoints_rad[0], dtype=float)
        self.v = np.zeros_like(self.q)
        self.command: RobotCommandMsg | None = None
        self.braking = False  # on its own, along the expired command's stop
        self.segment: tuple[float, np.ndarray, float, np.ndarray] | None = None
        """The segment being followed: ``(t_from, q_from, t_to, q_to)``."""
        self.refused = 0
        self.stop_event = threading.Event()
        self.sub = bus.subscribe(keys.robot_command_key(self.cell), Decoder(), capacity=64)
        self.pub = bus.publisher(keys.robot_state_key(self.cell))

    def _newest(self) -> RobotCommandMsg | None:
        got = [
            d.msg
            for d in self.sub.drain().messages
            if isinstance(d.msg, RobotCommandMsg) and len(d.msg.q) == len(self.q)
        ]
        return max(got, key=lambda m: m.seq) if got else None

    def tick(self, now: float) -> None:
        cmd = self._newest()
        if cmd is not None and self._acceptable(cmd, now):
            # from where the robot is now to the new set point, reached at stamp + dt
            t_to = max(cmd.stamp_s + self.dt_s, now)
            self.segment = (now, self.q.copy(), t_to, np.asarray(cmd.q, dtype=float))
            self.command, self.braking = cmd, False
        if self.command is None or self.segment is None:
            self.publish(now)
            return
        if now <= self.segment[2]:
            self._apply(*self._on_segment(now))
        else:  # past the set point without a newer command: on its verified stop, on schedule
            if now > self.command.valid_until_s and not self.braking:
                log.warning("commands expired: braking along the last verified stop")
                self.braking = True
            self._apply(*stop_position(self.command, now))
        self.publish(now)

    def _acceptable(self, cmd: RobotCommandMsg, now: float) -> bool:
        """A command is followed while valid; once the robot brakes on its own (the newest
        command expired), only one whose set point is where the robot stands (the worker
        re-anchored on the measured state)."""
        if self.command is not None and cmd.seq <= self.command.seq:
            return False
        if not self.braking and now <= cmd.valid_until_s:
            return True
        if float(np.max(np.abs(np.asarray(cmd.q) - self.q))) <= self.tol_rad:
            return True
        self.refused += 1
        return False

    def _on_segment(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity at ``t_s`` on the straight segment to the newest set point."""
        if self.segment is None:
            return self.q, np.zeros_like(self.q)
        t0, q0, t1, q1 = self.segment
        if t1 <= t0:
            return q1, np.zeros_like(q1)
        slope = (q1 - q0) / (t1 - t0)
        return q0 + slope * (min(t_s, t1) - t0), slope

    def _apply(self, q: np.ndarray, v: np.ndarray) -> None:
        """The robot's set point (an ideal robot: reached at once)."""
        self.q, self.v = q, v

    def publish(self, now: float) -> None:
        self.pub.put(
            RobotStateMsg(
                seq=self.pub.next_seq(), stamp_s=now, q=self.q.tolist(), q_dot=self.v.tolist()
            )
        )

    def run(self, duration_s: float | None = None) -> None:
        t_end = None if duration_s is None else time.monotonic() + duration_s
        next_t = time.monotonic()
        while not self.stop_event.is_set():
            if t_end is not None and time.monotonic() >= t_end:
                break
            try:
                self.tick(time.time())
            except Exception:  # noqa: BLE001 - keep braking rather than die
                log.exception("controller tick failed")
            next_t += 0.5 * self.dt_s
            time.sleep(max(next_t - time.monotonic(), 20e-6))
            if next_t < time.monotonic() - self.dt_s:  # late: no catching up
                next_t = time.monotonic()


def main(argv: list[str] | None = None) -> int:
    return process_main("controller", "the reference robot controller", Controller, argv)


if __name__ == "__main__":
    sys.exit(main())
