"""The replayer: publishes a scenario's people over Zenoh as a tracking system would, in real
time, at each person's sensor rate (the built-in demo's stand-in for a real tracker).

A skeleton stamped ``t`` carries the pose of scenario time ``t - t0 - delay`` (the parameter
set's sensor delay), with the scenario's sensor noise, so the cell sees exactly what its models
assume; it is of the kind the person's sensor tracks (``sensor.tracks``: an upper-body
recording's legs, which the replay stands on the floor, are not sent; the simulator does the
same). Adversaries chase the robot as commanded on ``sara/<cell>/robot/command``; only a
scenario with such a person makes the replayer subscribe to the commands (500 a second, each a
copy the router sends). A command of another joint count than the scenario's robot is counted
and logged, not followed. The scenario restarts after ``sim.duration_s``; an accepted scenario
update (``params/ack``) restarts it with the new people. Like a real tracker it sends a frame
(``TrackerFrameMsg``) as the scenario's first declared tracker (``inputs.trackers[0]``,
``main`` by default), listing the people it publishes, at ``FRAME_HZ``: without them the cell
would not move (silence is not an empty cell). The other declared trackers are yours: a
replayer that spoke for every declared tracker answered for a real tracker's people too (and
its frames, not listing them, forgot them: hostile-tracker probe, 2026-11-30).
"""

from __future__ import annotations

import logging
import sys
import threading
import time

import numpy as np

from sara_app.bus import keys
from sara_app.bus.codec import Decoder
from sara_app.bus.messages import (
    ParamsAckMsg,
    ParamsMsg,
    RobotCommandMsg,
    SkeletonMsg,
    TrackerFrameMsg,
)
from sara_app.bus.process import SummarisedWarning, process_main
from sara_app.bus.request_queue import requests
from sara_app.bus.session import Bus, Publisher, Subscription
from sara_app.errors import SaraError
from sara_app.geometry.poses import pose_from_xyz_rpy
from sara_app.human.glitches import Glitches
from sara_app.human.params import to_reach_params
from sara_app.human.skeleton import UPPER_JOINTS
from sara_app.robot.model import RobotModel
from sara_app.scenario import Scenario, parse_scenario
from sara_app.sim.motions import (
    HumanMotion,
    make_motion,
    measured,
    measures_legs,
    reacts_to_robot,
)

log = logging.getLogger("sara_app.replayer")
FRAME_HZ = 50.0
_MIN_SLEEP_S = 1e-4
"""Never a busy loop (a skeleton already due: the next tick after this)."""
_MAX_SLEEP_S = 0.02
"""Commands and scenario edits are taken at least this often, skeletons or not."""


class Replayer:
    def __init__(self, cell: str, scenario: Scenario, bus: Bus, *, seed: int = 0) -> None:
        self.cell = keys.check_name("cell", cell)
        self.bus = bus
        self.rng = np.random.default_rng(seed)
        self.stop_event = threading.Event()
        dec = Decoder()
        self._decoder = dec
        self.sub_cmd: Subscription | None = None
        """The robot's commands, while a person chases the robot (:func:`reacts_to_robot`)."""
        self.commands_ignored = 0
        """Commands of another joint count than the scenario's robot (a worker for another
        robot on the cell's key): the chasing people keep the robot's last position."""
        self._ignored_log = SummarisedWarning(log, "robot commands ignored")
        self.sub_params = requests(bus, keys.params_key(self.cell), dec)
        self.sub_ack = requests(bus, keys.params_ack_key(self.cell), dec)
        self._pending: dict[str, dict] = {}
        self.pubs: dict[str, Publisher] = {}
        self.frame_pubs: dict[str, Publisher] = {}
        self.next_frame_s = 0.0
        # The people move as the scenario it started with says people move, also after an
        # edit: an edited human model changes what the cell assumes, not how fast the people
        # are (followed, a smaller set slowed the replayed person down to fit it).
        self.motion_params = to_reach_params(scenario.param_set(), "full")
        self.load(scenario)

    def load(self, sc: Scenario) -> None:
        self.scenario = sc
        self.params = to_reach_params(sc.param_set(), "full")
        T = pose_from_xyz_rpy(sc.robot.base_xyz_m, sc.robot.base_rpy_rad)
        self.robot: RobotModel = sc.robot.load(T, margin=False)
        self.q = np.asarray(sc.task.waypoints_rad[0], dtype=float)
        self.motions: list[HumanMotion] = []  # this scenario's people: built afresh
        self._restart(time.time())

    def _restart(self, now: float) -> None:
        """The scenario from its start. A motion whose poses depend on time alone (scripted,
        a recording: not :func:`reacts_to_robot`) is built once per scenario and replayed
        again; building it at every loop (0.12 s for ``punches``, more on a busy machine) held
        the frames back past the cell's tracker timeout, and the cell faulted and braked every
        time the demo looped (every 20 s in ``serve``'s log). A person who chases the robot
        carries its own state and starts afresh."""
        self.t0 = now
        built: list[HumanMotion | None] = [*self.motions] or [None] * len(self.scenario.humans)
        self.motions = [
            m if m is not None and not reacts_to_robot(m) else make_motion(h, self.motion_params)
            for h, m in zip(self.scenario.humans, built, strict=True)
        ]
        self.kinds = [
            "full" if measures_legs(m, h.sensor.tracks) else "upper"
            for h, m in zip(self.scenario.humans, self.motions, strict=True)
        ]  # what each person's tracker measures (the legs of an upper-body source: nothing)
        self.next_s = [now for _ in self.scenario.humans]
        self.glitches = [Glitches(h.sensor.glitches) for h in self.scenario.humans]
        self._follow_robot(any(reacts_to_robot(m) for m in self.motions))
        for h in self.scenario.humans:
            if h.id not in self.pubs:
                self.pubs[h.id] = self.bus.publisher(keys.skeleton_key(self.cell, h.id))
        tid = self.scenario.inputs.trackers[0]
        if tid not in self.frame_pubs:
            self.frame_pubs[tid] = self.bus.publisher(keys.tracker_frame_key(self.cell, tid))

    def _follow_robot(self, follow: bool) -> None:
        """Subscribe to the robot's commands, or stop, as the people need them."""
        if follow and self.sub_cmd is None:
            self.sub_cmd = self.bus.subscribe(keys.robot_command_key(self.cell), self._decoder)
        elif not follow and self.sub_cmd is not None:
            self.sub_cmd.close()
            self.sub_cmd = None

    def _inputs(self) -> None:
        if self.sub_cmd is not None:  # where the robot is now: the newest command
            for d in self.sub_cmd.drain_latest().messages:
                if not isinstance(d.msg, RobotCommandMsg):
                    continue
                if len(d.msg.q) == self.robot.n_dof:
                    self.q = np.asarray(d.msg.q)
                else:
                    self.commands_ignored += 1
                    self._ignored_log(
                        f"{len(d.msg.q)} joints where this robot has {self.robot.n_dof}; the "
                        "people chase the robot where its last valid command put it"
                    )
        for d in self.sub_params.drain().messages:
            if isinstance(d.msg, ParamsMsg):
                self._pending[d.msg.request_id] = d.msg.scenario
        for d in self.sub_ack.drain().messages:
            if isinstance(d.msg, ParamsAckMsg):
                data = self._pending.pop(d.msg.request_id, None)
                if d.msg.accepted and data is not None:
                    try:
                        self.load(parse_scenario(data, "params message"))
                    except SaraError as e:
                        log.warning("accepted scenario cannot be replayed: %s", e)

    def tick(self, now: float) -> int:
        """Publish every skeleton that is due; returns how many were sent."""
        self._inputs()
        t_scn = now - self.t0 - self.params.delay_s
        if t_scn > self.scenario.sim.duration_s:
            self._restart(now)
            t_scn = -self.params.delay_s
        capsules: tuple[np.ndarray, np.ndarray] | None = None  # the robot's, when one is due
        sent = 0
        for i, (h, m) in enumerate(zip(self.scenario.humans, self.motions)):
            if now < self.next_s[i]:
                continue
            if capsules is None:
                capsules = self.robot.link_capsules(self.q)
            y = m.pose(max(t_scn, 0.0), *capsules)
            self.next_s[i] = max(self.next_s[i] + 1.0 / h.sensor.rate_hz, now - 0.5)
            y = self.glitches[i].apply(t_scn, measured(y, h.sensor.noise_m, self.rng))
            pub = self.pubs[h.id]
            kind = self.kinds[i]
            if kind == "upper":
                y = y[: len(UPPER_JOINTS)]  # the full body's first joints
            msg = SkeletonMsg.from_arrays(kind, y, seq=pub.next_seq(), stamp_s=now)
            sent += pub.put(msg)
        if now >= self.next_frame_s:
            self.next_frame_s = max(self.next_frame_s + 1.0 / FRAME_HZ, now - 0.5)
            self.publish_frames(now)
        return sent

    def publish_frames(self, now: float) -> None:
        """A frame as the first declared tracker: every person of the scenario is in view."""
        people = [h.id for h in self.scenario.humans]
        pub = self.frame_pubs[self.scenario.inputs.trackers[0]]
        pub.put(TrackerFrameMsg(seq=pub.next_seq(), stamp_s=now, people=people))

    def run(self, duration_s: float | None = None) -> None:
        """Tick whenever a skeleton or frame is due, as a tracker publishes: on its own frame
        clock (a loop polling at half a frame period stamped its skeletons up to that late,
        at a phase that wandered from frame to frame)."""
        t_end = None if duration_s is None else time.monotonic() + duration_s
        while not self.stop_event.is_set():
            if t_end is not None and time.monotonic() >= t_end:
                break
            try:
                self.tick(time.time())
            except Exception:  # noqa: BLE001 - a replay glitch must not end the demo
                log.exception("replayer tick failed")
            due_s = min([self.next_frame_s, *self.next_s])
            time.sleep(min(max(due_s - time.time(), _MIN_SLEEP_S), _MAX_SLEEP_S))


def main(argv: list[str] | None = None) -> int:
    # its skeletons carry their publication time (sara-app bench --live measures from it)
    return process_main("replayer", "replay scenario humans", Replayer, argv, timestamped=True)


if __name__ == "__main__":
    sys.exit(main())
