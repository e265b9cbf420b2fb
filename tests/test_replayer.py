"""The replayer (the demo's stand-in for a tracker) over real Zenoh on 127.0.0.1: it publishes on
its own frame clock, and it listens to the robot's commands only while a person in its
scenario chases the robot."""

from __future__ import annotations

import logging
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

from sara_app.bus import keys
from sara_app.bus.messages import RobotCommandMsg, SkeletonMsg
from sara_app.bus.session import Bus, free_port
from sara_app.peers.replayer import Replayer
from sara_app.scenario import load_scenario

CELL = "rp"


def _command(q: list[float], seq: int) -> RobotCommandMsg:
    now = time.time()
    n = len(q)
    return RobotCommandMsg(seq=seq, stamp_s=now, q=q, q_dot=[0.0] * n, q_ddot=[0.0] * n,
                           mode="rest", valid_until_s=now + 0.01)  # fmt: skip


def _command_until(
    replayer: Replayer, pub: Any, q_of: Callable[[int], list[float]], done: Callable[[], bool],
    seq: int = 0,
) -> int:  # fmt: skip
    """Put command ``seq`` (set point ``q_of(seq)``) on ``pub`` every 10 ms, ticking
    ``replayer`` after each, until ``done()`` or 5 s passed; the next ``seq``."""
    t_end = time.monotonic() + 5.0
    while not done() and time.monotonic() < t_end:
        pub.put(_command(q_of(seq), seq))
        seq += 1
        time.sleep(0.01)
        replayer.tick(time.time())
    return seq


def test_only_a_person_who_chases_the_robot_makes_it_follow_the_commands() -> None:
    port = free_port()
    with Bus.router(port), Bus.client(port) as rb, Bus.client(port) as tb:
        scripted = Replayer(CELL, load_scenario("punches"), rb)
        assert scripted.sub_cmd is None  # scripted people: no copy of 500 commands a second
        adversarial = load_scenario("adversarial")
        scripted.load(adversarial)  # an accepted edit that brings in an adversary
        assert scripted.sub_cmd is not None
        pub = tb.publisher(keys.robot_command_key(CELL))
        q = [0.1, -0.2, 0.3, -1.5, 0.0, 1.8, 0.7]
        _command_until(scripted, pub, lambda seq: q, lambda: np.allclose(scripted.q, q))
        np.testing.assert_allclose(scripted.q, q)  # the adversary chases where the robot is
        scripted.load(load_scenario("punches"))
        assert scripted.sub_cmd is None  # and stops listening when nobody chases it


def test_a_command_of_another_joint_count_is_counted_and_logged_not_followed(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """A worker for another robot on the cell's key: its commands are ignored for the chasing
    person, but counted and said (they were dropped unseen before)."""
    port = free_port()
    q = [0.1, -0.2, 0.3, -1.5, 0.0, 1.8, 0.7]
    with Bus.router(port), Bus.client(port) as rb, Bus.client(port) as tb:
        replayer = Replayer(CELL, load_scenario("adversarial"), rb)
        pub = tb.publisher(keys.robot_command_key(CELL))
        with caplog.at_level(logging.WARNING, logger="sara_app.replayer"):
            seq = _command_until(
                replayer, pub, lambda seq: [0.5] * (6 + 2 * (seq % 2)),  # 6 and 8 joints
                lambda: replayer.commands_ignored >= 2,
            )  # fmt: skip
        assert replayer.commands_ignored >= 2
        np.testing.assert_allclose(replayer.q, load_scenario("adversarial").task.waypoints_rad[0])
        assert "robot commands ignored" in caplog.text and "where this robot has 7" in caplog.text
        # a valid one after them is followed
        _command_until(replayer, pub, lambda seq: q, lambda: np.allclose(replayer.q, q), seq)
        np.testing.assert_allclose(replayer.q, q)


@pytest.mark.exclusive
@pytest.mark.exclusive  # asserts the period of a real thread (failed once beside a light test)
@pytest.mark.usefixtures("idle_cpus_poll")
def test_skeletons_are_stamped_on_the_frame_clock() -> None:
    """At the person's sensor rate, one skeleton per frame period: a frame clock, not a poll
    (which stamped skeletons up to half a period late and sent two in one poll after a late
    one)."""
    sc = load_scenario("punches")
    rate = sc.humans[0].sensor.rate_hz
    port = free_port()
    with Bus.router(port), Bus.client(port) as rb, Bus.client(port) as tb:
        sub = tb.subscribe(keys.skeleton_key(CELL, sc.humans[0].id), fifo=True, capacity=10000)
        rep = Replayer(CELL, sc, rb)
        thread = threading.Thread(target=rep.run, kwargs={"duration_s": 2.0}, daemon=True)
        thread.start()
        thread.join(10)
        time.sleep(0.1)
        stamps = np.array([d.msg.stamp_s for d in sub.drain().messages
                           if isinstance(d.msg, SkeletonMsg)])  # fmt: skip
    assert len(stamps) >= 1.5 * rate
    gaps = np.diff(stamps)
    assert abs(np.median(gaps) - 1.0 / rate) < 0.1 / rate
    # on the clock: each stamp a whole number of periods after the one before, give or take
    # the wake-up (a poll at half a period would scatter the gaps over half a period)
    off = np.abs(gaps * rate - np.round(gaps * rate))
    assert np.mean(off < 0.25) > 0.95, np.percentile(off, [50, 90])


def test_the_replayer_imports_no_shield_and_no_optimizer() -> None:
    """The replayer publishes people; it needs the scenario, the motions and the robot model,
    not the shield and its kernels (it imported them for a pose helper: 1.2 s more before its
    first skeleton, a 'no frame received' fault at every start as long) nor scipy's optimizer
    (a capsule fit's, only on a cache miss)."""
    heavy = ("sara_app.cell.build", "sara_app.safety.shield", "scipy.optimize")
    code = (
        "import sys\nimport sara_app.peers.replayer\n"
        f"print(sorted(m for m in {heavy!r} if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True).stdout  # fmt: skip
    assert out.strip().splitlines()[-1] == "[]", out[-500:]


def test_an_edited_human_model_does_not_change_how_the_people_move() -> None:
    """The replayer stands for real people: after an accepted edit that shrinks the human
    model's bounds, its scripted person punches as fast as before (it slowed down to fit the
    edited set, so the cell's monitor had nothing to flag and the edit looked safe)."""
    from sara_app.human.params import load_param_set
    from sara_app.scenario import parse_scenario

    sc = load_scenario("punches")
    data = sc.model_dump(mode="json")
    tiny = load_param_set(data["human_params"]).model_dump(mode="json")
    for joint in tiny["joints"].values():
        joint["v_max_mps"], joint["a_max_mps2"] = 0.05, 0.5
    data["human_params"] = {**tiny, "name": "tiny"}
    port = free_port()
    with Bus.router(port), Bus.client(port) as rb:
        rep = Replayer(CELL, sc, rb)
        before = rep.motion_params.v_max_mps.copy()
        rep.load(parse_scenario(data))  # an accepted edit
        assert np.all(rep.params.v_max_mps == 0.05)  # what the cell assumes now
        np.testing.assert_array_equal(rep.motion_params.v_max_mps, before)  # how they move
        assert before.max() > 1.0


def test_a_person_tracked_upper_body_is_sent_as_an_upper_body_skeleton() -> None:
    """The handover tracked upper-body only (`sensor.tracks: upper`): the replayer sends the
    upper body alone, so the cell treats the legs as unmeasured (it sent the replay's standing
    legs as a full-body skeleton, and the live cell took them for measured ones); a full-body
    person stays full-body."""
    port = free_port()
    with Bus.router(port), Bus.client(port) as rb, Bus.client(port) as tb:
        for name, kind, joints in (("bench_handover_upper", "upper", 9), ("punches", "full", 15)):
            sc = load_scenario(name)
            sub = tb.subscribe(keys.skeleton_key(CELL, sc.humans[0].id), fifo=True)
            rep = Replayer(CELL, sc, rb)
            got: list[SkeletonMsg] = []
            t_end = time.monotonic() + 5.0
            while not got and time.monotonic() < t_end:
                rep.tick(time.time())
                time.sleep(0.02)
                got = [d.msg for d in sub.drain().messages if isinstance(d.msg, SkeletonMsg)]
            assert got, name
            y, _ = got[0].to_arrays()
            assert got[0].kind == kind and y.shape == (joints, 3), (name, got[0].kind, y.shape)
            sub.close()


def test_the_demo_loops_without_building_its_people_again() -> None:
    """At the scenario's end the replayer starts it again. A person whose motion depends on time
    alone (scripted, recorded) keeps the motion built at the scenario's load: building it again
    took 0.12 s for ``punches`` and held the frames back past the cell's tracker timeout, so
    ``serve``'s cell faulted at every loop. A person who chases the robot starts afresh."""
    port = free_port()
    with Bus.router(port), Bus.client(port) as rb:
        for name, rebuilt in (("punches", False), ("bench_worker", False), ("adversarial", True)):
            rep = Replayer(CELL, load_scenario(name), rb)
            before = list(rep.motions)
            end = rep.t0 + rep.params.delay_s + rep.scenario.sim.duration_s + 0.01
            rep.tick(end)
            assert rep.t0 == end, name  # started again
            assert [m is b for m, b in zip(rep.motions, before, strict=True)] == [
                not rebuilt
            ] * len(before), name
            rep.load(load_scenario(name))  # an accepted edit: its people built afresh
            assert not any(m is b for m, b in zip(rep.motions, before, strict=True)), name
