"""The cell's bridge to a ROS 2 system that runs rmw_zenoh (enabled by the scenario's ``ros2``).

Two zenoh sessions: one to the cell's router (as the ``controller`` user: it publishes the robot
state), one to the ROS 2 system's router (rmw_zenoh's ``zenohd``, ``ros2.router``). It

- publishes every command of the cell as ``sensor_msgs/JointState`` on ``ros2.command_topic``
  (positions and velocities of the set point, the robot's joint names);
- publishes the occupancy as ``visualization_msgs/MarkerArray`` on ``ros2.occupancy_topic`` at
  most ``ros2.occupancy_hz`` times a second (RViz, Foxglove);
- reads ``sensor_msgs/JointState`` on ``ros2.state_topic`` as the measured robot state and
  publishes it on the cell's ``robot/state`` (matched by joint name; a sample without every
  joint, or without velocities, is dropped and counted: the cell's freshness rule then holds
  the robot on its verified stop);

with rmw_zenoh's key expressions, attachments and liveliness tokens (:mod:`.topics`) and CDR
payloads from the CDR library (:mod:`.interfaces`). It never runs in the worker: a late or
stopped bridge is a late or stopped robot state, which the cell already handles fail-safe.
"""

from __future__ import annotations

import logging
import threading
import time
import uuid
from typing import Any

import zenoh

from sara_app.bus import keys
from sara_app.bus.codec import Decoder
from sara_app.bus.messages import OccupancyMsg, RobotCommandMsg, RobotStateMsg
from sara_app.bus.process import process_main
from sara_app.bus.session import PRIORITY_OF_LANE, Bus
from sara_app.errors import SaraError
from sara_app.ros2.convert import command_joint_state, occupancy_markers, robot_state
from sara_app.ros2.interfaces import codec
from sara_app.ros2.topics import attachment, liveliness_key, topic_key
from sara_app.scenario import Ros2Spec, Scenario

log = logging.getLogger("sara_app.ros2")
JOINT_STATE = "sensor_msgs/msg/JointState"
MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
NODE = "sara_cell"
POLL_S = 0.001


class Ros2Bridge:
    """Forwards between ``cell_bus`` (the cell's session) and ``ros`` (a session on the ROS 2
    system's router) for robot ``joint_names``; :meth:`run` until ``stop_event``."""

    def __init__(
        self,
        cell: str,
        spec: Ros2Spec,
        joint_names: tuple[str, ...],
        cell_bus: Bus,
        ros: zenoh.Session,
    ) -> None:
        self.cell, self.spec, self.names, self.ros = cell, spec, joint_names, ros
        self.encode_js, self.decode_js = codec(JOINT_STATE)
        self.encode_markers = codec(MARKER_ARRAY)[0]
        self.gid = uuid.uuid4().bytes
        self.counts = dict.fromkeys(("commands", "markers", "states", "states_dropped"), 0)
        self.stop_event = threading.Event()
        d = spec.domain_id
        self.key_command = topic_key(d, spec.command_topic, JOINT_STATE)
        self.key_markers = topic_key(d, spec.occupancy_topic, MARKER_ARRAY)
        self.key_state = topic_key(d, spec.state_topic, JOINT_STATE)
        # in the lanes of the cell's own keys (the contract's "Lanes"): the robot's first
        self.pub_command = ros.declare_publisher(
            self.key_command, priority=PRIORITY_OF_LANE["control"]
        )
        self.pub_markers = ros.declare_publisher(
            self.key_markers, priority=PRIORITY_OF_LANE["display"]
        )
        self._seq = 0
        self._next_markers = 0.0
        dec = Decoder()
        self.sub_cmd = cell_bus.subscribe(keys.robot_command_key(cell), dec, fifo=True)
        self.sub_occ = cell_bus.subscribe(keys.occupancy_key(cell), dec)
        self.pub_state = cell_bus.publisher(keys.robot_state_key(cell))
        self._state_lock = threading.Lock()
        self.sub_state = ros.declare_subscriber(self.key_state, self._on_state)
        zid = str(ros.info.zid())
        tokens = [liveliness_key(d, zid, 0, 0, "NN", NODE)]
        tokens += [liveliness_key(d, zid, 0, i + 1, kind, NODE, topic=t, type_name=ty)
                   for i, (kind, t, ty) in enumerate((
                       ("MP", spec.command_topic, JOINT_STATE),
                       ("MP", spec.occupancy_topic, MARKER_ARRAY),
                       ("MS", spec.state_topic, JOINT_STATE)))]  # fmt: skip
        self.tokens = [ros.liveliness().declare_token(k) for k in tokens]

    def _put(self, pub: Any, payload: bytes) -> None:
        self._seq += 1
        pub.put(payload, attachment=attachment(self._seq, time.time_ns(), self.gid))

    def _on_state(self, sample: zenoh.Sample) -> None:
        """A JointState from ROS: the cell's robot state, or dropped and counted."""
        try:
            js = self.decode_js(sample.payload.to_bytes())
            q, qd, stamp = robot_state(js, self.names)
            with self._state_lock:
                msg = RobotStateMsg(seq=self.pub_state.next_seq(), stamp_s=stamp, q=q, q_dot=qd)
                self.pub_state.put(msg)
            self.counts["states"] += 1
        except (SaraError, ValueError, IndexError, AttributeError) as e:
            self.counts["states_dropped"] += 1
            log.warning("ROS 2 JointState dropped: %s", e)

    def step(self, now: float) -> None:
        """Forward what the cell published since the last step."""
        for d in self.sub_cmd.drain().messages:
            if isinstance(d.msg, RobotCommandMsg):
                js = command_joint_state(d.msg, self.names, self.spec.frame_id)
                self._put(self.pub_command, self.encode_js(js))
                self.counts["commands"] += 1
        occ = [d.msg for d in self.sub_occ.drain().messages if isinstance(d.msg, OccupancyMsg)]
        if occ and now >= self._next_markers:
            self._next_markers = now + 1.0 / self.spec.occupancy_hz
            markers = occupancy_markers(occ[-1], self.spec.frame_id)
            self._put(self.pub_markers, self.encode_markers(markers))
            self.counts["markers"] += 1

    def run(self, duration_s: float | None = None) -> None:
        t_end = None if duration_s is None else time.monotonic() + duration_s
        while not self.stop_event.is_set():
            now = time.monotonic()
            if t_end is not None and now >= t_end:
                break
            try:
                self.step(now)
            except (SaraError, ValueError) as e:  # one bad message, never the bridge
                log.warning("ROS 2 bridge: %s", e)
            time.sleep(POLL_S)

    def close(self) -> None:
        self.stop_event.set()
        for t in self.tokens:
            t.undeclare()
        self.sub_state.undeclare()
        self.pub_command.undeclare()
        self.pub_markers.undeclare()


def ros_session(endpoint: str) -> zenoh.Session:
    """A client session on the ROS 2 system's router ``endpoint`` (e.g. tcp/127.0.0.1:7447)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", f'["{endpoint}"]')
    conf.insert_json5("scouting/multicast/enabled", "false")
    # no shared-memory pool set up in the relay's loop (sara_app.bus.session.NO_SHARED_MEMORY)
    conf.insert_json5("transport/shared_memory/enabled", "false")
    return zenoh.open(conf)


class BridgeProcess:
    """The bridge as a cell process (``serve`` starts it when ``scenario.ros2.enabled``)."""

    def __init__(self, cell: str, sc: Scenario, bus: Bus) -> None:
        self.ros = ros_session(sc.ros2.router)
        names = sc.robot.load(margin=False).joint_names
        self.bridge = Ros2Bridge(cell, sc.ros2, names, bus, self.ros)
        self.stop_event = self.bridge.stop_event

    def run(self, duration_s: float | None = None) -> None:
        try:
            self.bridge.run(duration_s)
        finally:
            self.bridge.close()
            self.ros.close()


def main(argv: list[str] | None = None) -> int:
    return process_main("ros2", "the cell's ROS 2 bridge (rmw_zenoh)", BridgeProcess, argv)


if __name__ == "__main__":
    raise SystemExit(main())
