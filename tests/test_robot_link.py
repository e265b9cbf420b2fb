"""The measured robot of a live cell (``sara_app.runtime.robot_link``): the commanded position
at a state's time and its slack against a brute-force reading of the commanded trajectory
(straight segments through the set points, the newest command's stop after the last one, the
older command's stop bounding the slack), the faults it reports, and a clock that goes back."""

from __future__ import annotations

import bisect
import time
from types import SimpleNamespace

import numpy as np
import pytest

from sara_app.bus import keys
from sara_app.bus.compact import encode_compact
from sara_app.bus.messages import ControllerStatusMsg, RobotStateMsg, encode, position_on_stop
from sara_app.bus.session import Drained
from sara_app.robot.trajectory import JointState
from sara_app.runtime import robot_link
from sara_app.runtime.robot_link import (
    BRAKING_SAID_S,
    REFUSED_FAULT_S,
    REPLAN_STILL_S,
    STATE_SPEED_FACTOR,
    STOP_ENDS,
    MeasuredRobot,
    decoder,
)

N = 7
V_MAX = np.linspace(1.0, 2.6, N)  # rad/s


def _history(rng: np.random.Generator, n_points: int) -> MeasuredRobot:
    robot = MeasuredRobot()
    t = 1000.0
    q = rng.normal(size=N)
    for _ in range(n_points):
        t += rng.uniform(0.001, 0.004)
        q = q + rng.normal(scale=0.01, size=N)
        stop_t = t + np.cumsum(rng.uniform(0.005, 0.02, 4))
        stop_q = q + np.cumsum(rng.normal(scale=0.005, size=(4, N)), axis=0)
        robot.sent(t, q, (np.concatenate(([t], stop_t)), np.vstack((q, stop_q))))
    return robot


def _oracle(robot: MeasuredRobot, t_s: float) -> tuple[np.ndarray, float] | None:
    c = list(robot.commanded)
    if not c or t_s < c[0][0]:
        return None
    if t_s >= c[-1][0]:
        return position_on_stop(*c[-1][2], t_s)[0], 0.0
    k = bisect.bisect_right([e[0] for e in c], t_s) - 1
    (ta, qa, older), (tb, qb, _) = c[k], c[k + 1]
    q = qa + (qb - qa) * ((t_s - ta) / (tb - ta))
    return q, float(np.max(np.abs(position_on_stop(*older, t_s)[0] - q)))


def test_expected_is_the_commanded_trajectory() -> None:
    rng = np.random.default_rng(4)
    for n_points in (1, 2, 5, 300):  # 300: past the remembered history
        robot = _history(rng, n_points)
        c = robot.commanded
        times = [c[0][0] - 0.01, c[0][0], c[-1][0], c[-1][0] + 0.05]
        times += [e[0] for e in list(c)[::7]]
        times += list(rng.uniform(c[0][0] - 0.005, c[-1][0] + 0.03, 200))
        for t in times:
            got, want = robot.expected(t), _oracle(robot, t)
            if want is None:
                assert got is None
                continue
            assert got is not None
            np.testing.assert_array_equal(got[0], want[0])
            assert got[1] == want[1]


def test_faults_stale_tracking_and_a_clock_that_goes_back() -> None:
    rng = np.random.default_rng(9)
    robot = _history(rng, 20)
    t_mid = 0.5 * (robot.commanded[5][0] + robot.commanded[6][0])
    q_mid, slack = robot.expected(t_mid) or (np.zeros(N), 0.0)

    def state(t: float, q: np.ndarray) -> None:
        robot.state, robot.stamp_s = JointState(q, np.zeros(N), np.zeros(N)), t

    state(t_mid, q_mid)
    assert robot.faults(t_mid + 0.001, 0.05, 0.01) == []
    assert "old" in robot.faults(t_mid + 0.2, 0.05, 0.01)[0]
    state(t_mid, q_mid + 0.01 + slack + 1e-3)
    assert "tracking error" in robot.faults(t_mid + 0.001, 0.05, 0.01)[0]
    robot.refused_s = t_mid  # a state of the key refused: a fault for a while
    assert "refused" in robot.faults(t_mid + REFUSED_FAULT_S - 1e-3, 0.5, 0.01)[0]
    assert "tracking error" in robot.faults(t_mid + REFUSED_FAULT_S, 0.5, 0.01)[0]
    robot.sent(robot.commanded[0][0] - 1.0, q_mid, (np.array([0.0]), q_mid[None]))
    assert len(robot.commanded) == 1  # time went back: the history starts afresh


def test_a_replan_is_refused_unless_the_state_is_fresh_at_rest_and_where_confirmed() -> None:
    """Each condition of an operator's re-plan alone refuses it, naming the bad value."""
    lo, hi = -np.full(N, 2.9), np.full(N, 2.9)
    robot = MeasuredRobot()
    q = np.linspace(-0.5, 0.5, N)

    def why(q_seen: np.ndarray, now_s: float = 10.0) -> str | None:
        return robot.replan_refusal(q_seen, now_s, 0.05, 0.005, lo, hi)

    assert why(q) is not None and "no robot state" in str(why(q))
    robot.state, robot.stamp_s = JointState(q=q, v=np.zeros(N), a=np.zeros(N)), 10.0
    robot.still_since_s = 10.0 - REPLAN_STILL_S + 0.01
    assert "stood still for 0.29 s" in str(why(q))
    robot.still_since_s = 10.0 - REPLAN_STILL_S
    assert why(q) is None and why(q + 0.004) is None
    robot.refused_s = 10.0 - REPLAN_STILL_S + 0.01  # a state of the key refused just now
    assert "refused on its key" in str(why(q))
    robot.refused_s = 10.0 - REPLAN_STILL_S
    assert "0.0100 rad from the position confirmed" in str(why(q + 0.01))
    assert "[-0.5000, " in str(why(q + 0.01))  # where the controller says the robot is
    assert "old" in str(why(q, now_s=10.2))
    robot.state = JointState(q=q, v=np.full(N, 1e-3), a=np.zeros(N))
    assert "not at rest" in str(why(q))
    robot.state = JointState(q=q, v=np.full(N, np.nan), a=np.zeros(N))
    assert "not at rest" in str(why(q))  # NaN is never at rest
    beyond = q.copy()
    beyond[3] = 3.0
    robot.state = JointState(q=beyond, v=np.zeros(N), a=np.zeros(N))
    assert "joint 3 at 3.0000 rad is outside its limits" in str(why(beyond))
    robot.state = JointState(q=q, v=np.zeros(N), a=np.zeros(N))
    assert why(q) is None
    elsewhere = q + 0.01  # the automatic re-anchor (a stream not bound) needs the same evidence
    assert robot.at_rest_elsewhere(elsewhere, 10.0, 0.05, 0.005)
    robot.refused_s = 9.9
    assert not robot.at_rest_elsewhere(elsewhere, 10.0, 0.05, 0.005)
    robot.refused_s, robot.still_since_s = -np.inf, 9.9
    assert not robot.at_rest_elsewhere(elsewhere, 10.0, 0.05, 0.005)
    robot.still_since_s, robot.bound = 9.0, True
    assert not robot.at_rest_elsewhere(elsewhere, 10.0, 0.05, 0.005)  # bound: never


def test_the_robot_keys_decoder_refuses_another_joint_count_before_its_order() -> None:
    """A state of another number of joints with a huge ``seq`` is ``wrong_dof`` and does not
    hold the controller's next states back as out of order; a restart on another key is not
    this decoder's (it is the robot key's alone)."""
    dec, key = decoder(lambda: V_MAX), keys.robot_state_key("c1")

    def state(seq: int, n: int = N) -> bytes:
        return encode(RobotStateMsg(seq=seq, stamp_s=time.time(), q=[0.0] * n, q_dot=[0.0] * n))

    assert dec.decode(key, state(1)) is not None
    assert dec.decode(key, state(10**12, 3)) is None
    assert dec.decode(key, state(2)) is not None
    msg = RobotStateMsg(seq=3, stamp_s=time.time(), q=[0.0] * 3, q_dot=[0.0] * 3)
    assert dec.decode(key, encode_compact(msg)) is None  # compact records too
    assert dec.counts == {"wrong_dof": 2} and dec.restarts == 0
    stale = RobotStateMsg(seq=10**13, stamp_s=time.time() - 10.0, q=[0.0] * N, q_dot=[0.0] * N)
    assert dec.decode(key, encode(stale)) is None  # stamped long ago: never counts for the order
    assert dec.decode(key, state(4)) is not None and dec.counts["out_of_range"] == 1


def test_a_state_faster_than_any_drive_is_refused_by_the_robots_limits_in_force() -> None:
    """A state whose joint moves faster than ``STATE_SPEED_FACTOR`` times its velocity limit
    (either sign, 1e300 too) is ``out_of_range`` before it counts for the key's order; at the
    factor it is taken; the limits are read per message (an edit may change the robot)."""
    limits = [V_MAX]
    dec, key = decoder(lambda: limits[0]), keys.robot_state_key("c1")
    seq = iter(range(1, 100))

    def taken(q_dot: np.ndarray, compact: bool = False) -> bool:
        msg = RobotStateMsg(seq=next(seq), stamp_s=time.time(), q=[0.0] * N, q_dot=list(q_dot))
        return dec.decode(key, encode_compact(msg) if compact else encode(msg)) is not None

    at = STATE_SPEED_FACTOR * V_MAX
    assert taken(at) and taken(-at) and taken(at, compact=True)
    refused = 0
    for j in range(N):
        for v in (at[j] * (1 + 1e-9), -at[j] * 1.5, 1e300):
            fast = at.copy() * 0.5
            fast[j] = v
            assert not taken(fast) and not taken(fast, compact=True)
            refused += 2
    assert dec.counts == {"out_of_range": refused}
    assert taken(0.5 * at)  # the refused ones held nothing back
    limits[0] = V_MAX / 4  # a slower robot in force: the same speeds are now too fast
    assert not taken(0.5 * at) and taken(0.5 * at / 4)


class _States:
    """The robot key's subscription as :meth:`MeasuredRobot.drain` reads it: ``put`` states,
    ``drain`` hands them over (the subscription itself is tested in test_bus_session)."""

    def __init__(self) -> None:
        self.queue: list[RobotStateMsg] = []
        self.decoder = decoder(lambda: V_MAX)

    def drain(self, n: int) -> SimpleNamespace:
        got, self.queue = self.queue[:n], self.queue[n:]
        return SimpleNamespace(messages=[SimpleNamespace(msg=m) for m in got], refused_keys=0,
                               rejected=0)  # fmt: skip


def test_a_drivers_standstill_noise_is_at_rest_only_up_to_the_scenarios_rest_speed() -> None:
    """A real driver reports its velocity estimate's noise at standstill (here up to 3e-4
    rad/s): below the default rest speed (1e-6) the robot is never at rest, so no re-plan
    could ever start from it; with the scenario's rest speed at the driver's noise (1e-3) it
    is, after standing still for ``REPLAN_STILL_S``, and a state faster than that is not."""
    rng = np.random.default_rng(3)
    lo, hi = -np.full(N, 2.9), np.full(N, 2.9)
    q = np.linspace(-0.5, 0.5, N)
    for rest, at_rest in ((1e-6, False), (1e-3, True)):
        robot, sub = MeasuredRobot(), _States()
        robot.rest_speed = rest
        t = 100.0
        for k in range(200):  # 0.4 s at 500 Hz, standing within 0.1 mrad
            t = 100.0 + 0.002 * k
            v = rng.uniform(-3e-4, 3e-4, N)
            sub.queue.append(RobotStateMsg(seq=k, stamp_s=t, q=list(q + rng.normal(0, 2e-5, N)),
                                           q_dot=list(v)))  # fmt: skip
            robot.drain(sub, t, 0.005)  # type: ignore[arg-type]
        why = robot.replan_refusal(q, t, 0.05, 0.005, lo, hi)
        if at_rest:
            assert why is None
        else:
            assert "not at rest" in str(why) and "inputs.robot_rest_speed_rad_s" in str(why)
    sub.queue.append(RobotStateMsg(seq=999, stamp_s=t + 0.002, q=list(q), q_dot=[2e-3] * N))
    robot.drain(sub, t + 0.002, 0.005)  # type: ignore[arg-type]
    assert "not at rest" in str(robot.replan_refusal(q, t + 0.002, 0.05, 0.005, lo, hi))


class _Wire:
    """The robot key's subscription with the worker's real decoder: ``put`` states as the
    controller publishes them, ``drain`` decodes what has arrived (refusals counted)."""

    def __init__(self) -> None:
        self.queue: list[RobotStateMsg] = []
        self.decoder = decoder(lambda: V_MAX)
        self.key = keys.robot_state_key("c1")

    def drain(self, n: int) -> Drained:
        got, self.queue = self.queue[:n], self.queue[n:]
        before, out, refused = self.decoder.rejected, [], []
        for m in got:
            d = self.decoder.decode(self.key, encode(m))
            out.append(d) if d is not None else refused.append(self.key)
        return Drained(out, self.decoder.rejected - before, refused)


def test_a_router_stall_lets_the_plan_start_where_the_robot_braked_unless_disputed(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A bound stream, then a router stall: for ``stall_s`` the worker hears nothing while the
    controller goes on publishing at 1 kHz (braked on its own, its commands expired: at rest
    0.1 rad from the worker's plan), then the whole backlog arrives at once, the states older
    than 0.5 s refused as too old, the rest taken, then fresh states at rest. A second or more
    unheard unbinds the stream, though the states taken are less than a second apart by their
    stamps, and the worker may plan from where the robot rests (bound, the two waited on each
    other forever: soak probe 2026-12-04); after a shorter stall it may not. A second
    publisher lying with a huge ``seq`` after the stall makes the controller's states out of
    order: no plan from anywhere while they dispute."""
    clock = [time.time() - 100.0]  # the worker's clock (the decoder's age check reads it)
    monkeypatch.setattr(robot_link, "time", SimpleNamespace(time=lambda: clock[0]))
    q_plan, q_braked = np.zeros(N), np.full(N, 0.1)

    def state(seq: int, q: np.ndarray) -> RobotStateMsg:
        return RobotStateMsg(seq=seq, stamp_s=clock[0], q=list(q), q_dot=[0.0] * N)

    def run(stall_s: float, intruder: bool) -> tuple[bool, bool]:
        robot, wire = MeasuredRobot(), _Wire()
        seq = 0
        for _ in range(100):  # 0.2 s tracked at 500 Hz
            clock[0] += 0.002
            wire.queue.append(state(seq, q_plan))
            seq += 1
            robot.drain(wire, clock[0], 0.005)  # type: ignore[arg-type]
        robot.bound = True  # as its faults() leaves it while the states track the commands
        backlog = []
        for k in range(int(stall_s * 1000)):  # published, stuck in the stalled router
            clock[0] += 0.001
            backlog.append(state(seq, q_braked))
            seq += 1
            if k % 2:
                robot.drain(wire, clock[0], 0.005)  # type: ignore[arg-type]
        wire.queue += backlog
        unbound = False
        for k in range(300):  # the router resumed: the backlog, 64 a cycle, then fresh states
            clock[0] += 0.002
            if intruder and k % 5 == 0:
                wire.queue.append(state(10**12 + k, q_plan))
            wire.queue.append(state(seq, q_braked))
            seq += 1
            robot.drain(wire, clock[0], 0.005)  # type: ignore[arg-type]
            unbound = unbound or not robot.bound
        assert wire.decoder.counts.get("out_of_range", 0) > 100  # the late ones were refused
        return unbound, robot.at_rest_elsewhere(q_plan, clock[0], 0.05, 0.005)

    assert run(1.3, intruder=False) == (True, True)
    assert run(0.8, intruder=False) == (False, False)
    assert run(1.3, intruder=True)[1] is False


class _Status:
    """The controller's status key as :meth:`MeasuredRobot.hear_controller` reads it."""

    def __init__(self) -> None:
        self.queue: list[ControllerStatusMsg] = []

    def drain_latest(self) -> SimpleNamespace:
        got, self.queue = self.queue[-1:], []
        return SimpleNamespace(messages=[SimpleNamespace(msg=m) for m in got])


def test_a_bound_stream_may_be_planned_from_where_its_controller_braked_to_a_stops_end() -> None:
    """A controller whose commands expired brakes along the newest stop it has and rests at
    its end; a newer command that came late leaves the worker's plan resting elsewhere. Bound
    to the commands, the stream may be planned from there when its controller's newest status
    (at most ``BRAKING_SAID_S`` old) says it brakes on its own and the robot rests at the end
    of one of the stops the worker sent (at rest for ``REPLAN_STILL_S``); never from a rest
    anywhere else (a hostile or buggy controller's), nor at a stop's end without that word (a
    robot moved by hand along its path), nor once the commands are forgotten (a re-plan)."""
    rng = np.random.default_rng(5)
    robot, status = MeasuredRobot(), _Status()
    ends = []
    for k in range(300):  # more than STOP_ENDS: the oldest ends are forgotten
        t, q = 10.0 + 0.002 * k, rng.normal(size=N)
        end = q + 0.05
        robot.sent(t, q, (np.array([t, t + 0.1]), np.vstack((q, end))))
        if k % 3:  # a worker in fault sends one stop's end again and again: remembered once
            robot.sent(t + 0.001, q, (np.array([t, t + 0.1]), np.vstack((q, end))))
        ends.append(end)
    assert len(robot.stop_ends) == STOP_ENDS
    robot.bound = True
    plan = ends[-1]

    def said(braking: bool, now_s: float) -> None:
        for b in (not braking, braking):  # the newest counts
            status.queue.append(ControllerStatusMsg(
                seq=0, stamp_s=now_s, cell="c1", commands_received=1, commands_lost=0,
                commands_late=0, commands_expired=0, commands_refused=0, braking_events=1,
                worker_runs=1, braking=b,
            ))  # fmt: skip
        robot.hear_controller(status, now_s)  # type: ignore[arg-type]

    def rest_at(q: np.ndarray) -> bool:
        sub, t = _States(), 20.0
        for k in range(200):  # 0.4 s at rest at q
            t = 20.0 + 0.002 * k
            sub.queue.append(RobotStateMsg(seq=k, stamp_s=t, q=list(q), q_dot=[0.0] * N))
            robot.drain(sub, t, 0.005)  # type: ignore[arg-type]
        return robot.at_rest_elsewhere(plan, t, 0.05, 0.005)

    said(True, 20.0)
    assert rest_at(ends[-60] + 0.004)  # an older stop's end, within the tolerance
    assert not rest_at(ends[-60] + 0.3)  # elsewhere
    assert not rest_at(ends[10])  # a stop sent too long ago: forgotten
    assert not rest_at(plan)  # where the plan rests: nothing to re-anchor
    said(False, 20.0)
    assert not rest_at(ends[-60])  # no word that it braked: a robot moved by hand, say
    said(True, 20.4 - BRAKING_SAID_S - 0.01)
    assert not rest_at(ends[-60])  # the word is too old
    robot.bound = False
    assert rest_at(ends[-60] + 0.3)  # a stream not bound may be planned from anywhere
    robot.bound = True
    said(True, 20.0)
    robot.forget_commands()
    assert not rest_at(ends[-60])
