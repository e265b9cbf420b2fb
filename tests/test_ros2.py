"""ROS 2 over Zenoh without ROS: the type hash agrees with REP 2016's published value for
std_msgs/String; JointState and MarkerArray round-trip through the CDR library's own decoder;
the attachment through zenoh's own deserialiser; and the bridge, between a cell's router and a
second router standing for the ROS 2 system (both real, on 127.0.0.1), publishes commands and
occupancy on rmw_zenoh's key expressions, turns a ROS JointState into the cell's robot state by
joint name, drops (and counts) an incomplete one, and declares its liveliness tokens."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
import zenoh

from sara_app.bus import keys
from sara_app.bus.examples import example_messages
from sara_app.bus.messages import OccupancyMsg, RobotCommandMsg, RobotStateMsg
from sara_app.bus.session import Bus, free_port
from sara_app.geometry.shapes import quat_rotate
from sara_app.ros2.bridge import JOINT_STATE, MARKER_ARRAY, Ros2Bridge, ros_session
from sara_app.ros2.convert import header
from sara_app.ros2.interfaces import MARKER_CYLINDER, MARKER_DELETEALL, MARKER_SPHERE, codec
from sara_app.ros2.topics import attachment, read_attachment, topic_key
from sara_app.scenario import Ros2Spec

NAMES = ("j1", "j2", "j3")


def test_type_hash_and_keys_follow_rep_2016_and_rmw_zenoh() -> None:
    # the key rmw_zenoh's own documentation shows for /chatter
    assert topic_key(0, "/chatter", "std_msgs/msg/String") == (
        "0/chatter/std_msgs::msg::dds_::String_/"
        "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    )
    key = topic_key(3, "/sara/joint_command/", JOINT_STATE)
    assert key.startswith("3/sara/joint_command/sensor_msgs::msg::dds_::JointState_/RIHS01_")
    with pytest.raises(Exception, match="topic"):
        topic_key(0, "/", JOINT_STATE)


def test_messages_round_trip_through_the_cdr_library() -> None:
    enc, dec = codec(JOINT_STATE)
    js = {"header": header(12.5, "world"), "name": list(NAMES), "position": [0.1, -0.2, 0.3],
          "velocity": [1.0, 2.0, 3.0], "effort": []}  # fmt: skip
    data = enc(js)
    assert bytes(data[:4]) == b"\x00\x01\x00\x00"  # CDR little-endian encapsulation
    back = dec(data)
    assert list(back.name) == list(NAMES) and list(back.position) == [0.1, -0.2, 0.3]
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (12, 500_000_000)
    enc_m, dec_m = codec(MARKER_ARRAY)
    m = {"markers": [{"header": header(1.0, "world"), "ns": "x", "id": 7, "type": 3,
                      "scale": {"x": 0.1, "y": 0.1, "z": 0.5},
                      "color": {"r": 1.0, "g": 0.5, "b": 0.0, "a": 0.3}}]}  # fmt: skip
    out = dec_m(enc_m(m)).markers[0]
    assert (out.ns, out.id, out.type, out.scale.z) == ("x", 7, 3, 0.5)
    assert out.color.a == pytest.approx(0.3)


def test_a_set_cut_at_a_height_bound_is_a_triangle_list_below_its_cut() -> None:
    """An upper-body person's effective set with one capsule cut (legs bounded in height):
    the whole capsules as cylinders and spheres, the cut one as a TRIANGLE_LIST whose points
    all lie below the cut and within the capsule, encoded by the CDR library."""
    from sara_app.bus.messages import CapsulesMsg, HumanOccupancyMsg
    from sara_app.ros2.convert import occupancy_markers
    from sara_app.ros2.interfaces import MARKER_TRIANGLE_LIST

    occ = example_messages()["occupancy"][1]
    assert isinstance(occ, OccupancyMsg)
    ends = np.array([[[1.2, 0.0, 1.2], [1.2, 0.0, 1.6]], [[1.2, 0.0, 0.95], [1.2, 0.0, 0.95]],
                     [[1.3, 0.1, 1.3], [1.1, 0.1, 1.5]]])  # fmt: skip
    caps = CapsulesMsg.from_arrays(ends, np.array([0.1, 0.6, 0.1]), np.array([np.inf, 1.1, np.inf]))
    human = HumanOccupancyMsg(id="h1", kind="upper", joints_m=occ.humans[0].joints_m,
                              models={"effective": caps})  # fmt: skip
    out = occupancy_markers(occ.model_copy(update={"humans": [human]}), "world")["markers"]
    mine = [m for m in out if m["ns"].startswith("sara/human/h1/")]
    assert [m["type"] for m in mine if m["ns"] == "sara/human/h1/effective"] == [3, 2, 2] * 2
    (tri,) = [m for m in mine if m["ns"] == "sara/human/h1/effective/cut"]
    assert tri["type"] == MARKER_TRIANGLE_LIST and len(tri["points"]) % 3 == 0
    p = np.array([[q["x"], q["y"], q["z"]] for q in tri["points"]])
    assert len(p) > 100 and p[:, 2].max() <= 1.1 + 1e-6
    assert np.all(np.linalg.norm(p - [1.2, 0.0, 0.95], axis=1) <= 0.6 + 1e-6)
    enc, dec = codec(MARKER_ARRAY)
    back = [m for m in dec(enc({"markers": out})).markers if m.ns.endswith("/cut")]
    assert len(back) == 1 and len(back[0].points) == len(p)


def test_attachment_is_zenoh_serialised() -> None:
    gid = bytes(range(16))
    data = attachment(42, 1_700_000_000_123_456_789, gid)
    assert len(data) == 8 + 8 + 16
    assert data[:8] == (42).to_bytes(8, "little") and data[16:] == gid
    assert read_attachment(data) == (42, 1_700_000_000_123_456_789, gid)


class Rig:
    def __init__(self, cell_port: int, ros_port: int) -> None:
        self.cell_bus = Bus.client(cell_port)
        self.watch = Bus.client(cell_port)
        self.ros = ros_session(f"tcp/127.0.0.1:{ros_port}")
        self.bridge = Ros2Bridge("c1", Ros2Spec(enabled=True, router=f"tcp/127.0.0.1:{ros_port}"),
                                 NAMES, self.cell_bus, self.ros)  # fmt: skip
        self.thread = threading.Thread(target=self.bridge.run, daemon=True)
        self.thread.start()
        self.ros_side = ros_session(f"tcp/127.0.0.1:{ros_port}")  # a ROS 2 node's session

    def close(self) -> None:
        self.bridge.close()
        self.thread.join(5)
        for s in (self.ros, self.ros_side):
            s.close()
        self.cell_bus.close()
        self.watch.close()


@pytest.fixture()
def rig() -> Iterator[Rig]:
    cp, rp = free_port(), free_port()
    with Bus.router(cp), Bus.router(rp):
        r = Rig(cp, rp)
        try:
            yield r
        finally:
            r.close()


def _each_new(pub: Any, msg: Any) -> Any:
    """A sender putting ``msg`` with a new ``seq`` each call: the bridge, like every reader of
    the bus, refuses a repeated sequence number as out of order."""
    seq = iter(range(msg.seq, msg.seq + 1_000_000))
    return lambda: pub.put(msg.model_copy(update={"seq": next(seq)}))


def _receive(session: zenoh.Session, key: str, send: Any, timeout_s: float = 5.0) -> list:
    """Sends until ``session`` receives on ``key``: the first sends may reach the bridge before
    the subscriber's declaration has reached the router, so each send must be a new message."""
    got: list = []
    sub = session.declare_subscriber(key, lambda s: got.append(s))
    try:
        t_end = time.monotonic() + timeout_s
        while not got and time.monotonic() < t_end:
            send()
            time.sleep(0.05)
    finally:
        sub.undeclare()
    return got


def test_the_bridge_speaks_rmw_zenoh(rig: Rig) -> None:
    b = rig.bridge
    # the cell's command -> JointState on the rmw_zenoh key
    pub = rig.watch.publisher(keys.robot_command_key("c1"))
    cmd = RobotCommandMsg(seq=1, stamp_s=100.25, q=[0.1, 0.2, 0.3], q_dot=[0.0, 1.0, 0.0],
                          q_ddot=[0.0] * 3, mode="intended", valid_until_s=100.3)  # fmt: skip
    got = _receive(rig.ros_side, b.key_command, _each_new(pub, cmd))
    assert got, "no JointState on " + b.key_command
    js = codec(JOINT_STATE)[1](got[0].payload.to_bytes())
    assert list(js.name) == list(NAMES) and list(js.position) == [0.1, 0.2, 0.3]
    assert list(js.velocity) == [0.0, 1.0, 0.0] and js.header.frame_id == "world"
    seq, stamp_ns, gid = read_attachment(got[0].attachment.to_bytes())
    assert seq >= 1 and abs(stamp_ns / 1e9 - time.time()) < 60 and gid == b.gid
    assert str(got[0].priority) == str(zenoh.Priority.REAL_TIME)  # the robot's lane
    # the occupancy -> MarkerArray: cylinder + two spheres per capsule, after a DELETEALL
    occ = example_messages()["occupancy"][1]
    assert isinstance(occ, OccupancyMsg) and occ.robot is not None
    pub_occ = rig.watch.publisher(keys.occupancy_key("c1"))
    got = _receive(rig.ros_side, b.key_markers, _each_new(pub_occ, occ))
    assert got, "no MarkerArray on " + b.key_markers
    markers = codec(MARKER_ARRAY)[1](got[0].payload.to_bytes()).markers
    assert markers[0].action == MARKER_DELETEALL
    assert str(got[0].priority) == str(zenoh.Priority.DATA_LOW)  # the display's lane
    ends, radius = occ.robot.capsules.arrays()
    robot = [m for m in markers if m.ns == "sara/robot"]
    assert len(robot) == 3 * len(radius)
    for c in range(len(radius)):
        cyl, s0, s1 = robot[3 * c : 3 * c + 3]
        assert (cyl.type, s0.type, s1.type) == (MARKER_CYLINDER, MARKER_SPHERE, MARKER_SPHERE)
        axis = ends[c, 1] - ends[c, 0]
        o = cyl.pose.orientation
        z = quat_rotate(np.array([o.w, o.x, o.y, o.z]), np.array([0.0, 0.0, 1.0]))
        np.testing.assert_allclose(z * np.linalg.norm(axis), axis, atol=1e-9)
        p = cyl.pose.position
        np.testing.assert_allclose([p.x, p.y, p.z], ends[c].mean(axis=0), atol=1e-12)
        assert cyl.scale.z == pytest.approx(np.linalg.norm(axis))
        assert cyl.scale.x == s0.scale.x == pytest.approx(2 * radius[c])
        for s, e in ((s0, 0), (s1, 1)):
            np.testing.assert_allclose([s.pose.position.x, s.pose.position.y,
                                        s.pose.position.z], ends[c, e])  # fmt: skip
    assert any(m.ns.startswith("sara/human/") for m in markers)
    # a ROS JointState (another order, an extra joint) -> the cell's robot state, by name
    states = rig.watch.subscribe(keys.robot_state_key("c1"), fifo=True)
    enc = codec(JOINT_STATE)[0]
    ros_pub = rig.ros_side.declare_publisher(b.key_state)
    good = enc({"header": header(time.time(), "world"), "name": ["j3", "gripper", "j1", "j2"],
                "position": [3.0, 9.0, 1.0, 2.0], "velocity": [0.3, 0.0, 0.1, 0.2],
                "effort": []})  # fmt: skip
    t_end, seen = time.monotonic() + 5, []
    while not seen and time.monotonic() < t_end:
        ros_pub.put(good, attachment=attachment(1, time.time_ns(), bytes(16)))
        time.sleep(0.05)
        seen = [d.msg for d in states.drain().messages if isinstance(d.msg, RobotStateMsg)]
    assert seen, "no robot state from the ROS JointState"
    assert seen[0].q == [1.0, 2.0, 3.0] and seen[0].q_dot == [0.1, 0.2, 0.3]
    # incomplete (no j2) or without velocities: dropped and counted, nothing published
    before = b.counts["states_dropped"]
    for bad in ({"name": ["j1", "j3"], "position": [1.0, 3.0], "velocity": [0.0, 0.0]},
                {"name": list(NAMES), "position": [1.0, 2.0, 3.0], "velocity": []}):  # fmt: skip
        ros_pub.put(enc({"header": header(time.time(), "world"), "effort": [], **bad}))
    t_end = time.monotonic() + 5
    while b.counts["states_dropped"] < before + 2 and time.monotonic() < t_end:
        time.sleep(0.05)
    assert b.counts["states_dropped"] == before + 2
    time.sleep(0.2)
    assert not [d for d in states.drain().messages if isinstance(d.msg, RobotStateMsg)
                and d.msg.q != [1.0, 2.0, 3.0]]  # fmt: skip
    ros_pub.undeclare()
    # the graph: a node token and one per endpoint, as ROS 2 tools discover them
    replies = rig.ros_side.liveliness().get("@ros2_lv/**", timeout=5.0)
    found = sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)
    assert len(found) == 4 and any("/NN/%/%/sara_cell" in k for k in found)
    assert any(k.endswith("/MS/%/%/sara_cell/%joint_states/sensor_msgs::msg::dds_::"
                          f"JointState_/{b.key_state.rsplit('/', 1)[1]}/::,10:,:,:,,")
               for k in found)  # fmt: skip


def test_the_bridge_runs_as_the_cells_process(tmp_path: Any) -> None:
    """As serve starts it: its own process, the scenario's ros2 block, the cell's robot."""
    import json
    import subprocess
    import sys

    from sara_app.scenario import load_scenario

    cp, rp = free_port(), free_port()
    data = load_scenario("close_worker").model_dump(mode="json")
    data["ros2"] = {"enabled": True, "router": f"tcp/127.0.0.1:{rp}", "domain_id": 7}
    path = tmp_path / "ros_cell.json"
    path.write_text(json.dumps(data))
    names = load_scenario("close_worker").robot.load().joint_names
    with Bus.router(cp), Bus.router(rp), Bus.client(cp) as cell:
        cmd_line = [sys.executable, "-m", "sara_app.ros2.bridge", "--cell", "c1", "--scenario",
                    str(path), "--port", str(cp), "--duration", "60"]  # fmt: skip
        proc = subprocess.Popen(cmd_line)
        ros = ros_session(f"tcp/127.0.0.1:{rp}")
        try:
            pub = cell.publisher(keys.robot_command_key("c1"))
            zero = [0.0] * 7
            cmd = RobotCommandMsg(seq=1, stamp_s=time.time(), q=zero, q_dot=zero, q_ddot=zero,
                                  mode="failsafe", valid_until_s=time.time())  # fmt: skip
            got = _receive(ros, topic_key(7, "/sara/joint_command", JOINT_STATE),
                           _each_new(pub, cmd), timeout_s=60.0)  # fmt: skip
            assert got, "the bridge process forwarded no command"
            assert tuple(codec(JOINT_STATE)[1](got[0].payload.to_bytes()).name) == names
        finally:
            ros.close()
            proc.terminate()
            assert proc.wait(30) == 0
