"""serve's INFO terminal (sara_app.ops.health): state changes as they happen and one health line
a minute, from the live registry fed real verdict and controller-status messages."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from sara_app.api.registry import CellRegistry
from sara_app.bus.codec import Decoded
from sara_app.bus.keys import parse_key
from sara_app.bus.messages import ControllerStatusMsg, StatusMsg, VerdictMsg
from sara_app.ops.health import AGE_BIN_S, HealthLog, VerdictCounters, percentile_s
from sara_app.ops.stalls import Stall


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


def _feed(reg: CellRegistry, msg: object, key: str, t: float) -> None:
    reg.ingest(Decoded(parse_key(key), msg, t))  # type: ignore[arg-type]


def _verdict(seq: int, t: float, mode: str = "intended", **kw: object) -> VerdictMsg:
    return VerdictMsg(seq=seq, stamp_s=t, cell="c1", safety_mode="ssm", mode=mode,
                      cycle_time_us=100.0 + seq % 7, skeleton_age_s={"p1": 0.004},
                      **kw)  # type: ignore[arg-type]  # fmt: skip


def _controller(
    seq: int, t: float, received: int, braked: int, causes: dict, receive_failed: bool = False
) -> ControllerStatusMsg:
    return ControllerStatusMsg(seq=seq, stamp_s=t, cell="c1", commands_received=received,
                               commands_lost=0, commands_late=3, commands_expired=braked,
                               commands_refused=0, braking_events=braked, worker_runs=1,
                               braking=False, braking_causes=causes,
                               receive_failed=receive_failed)  # fmt: skip


def _status(t: float) -> StatusMsg:
    return StatusMsg(seq=0, stamp_s=t, cell="c1", state="running", scenario="punches",
                     uptime_s=1.0, humans=["p1"], cycle_time_p50_us=100.0,
                     cycle_time_p99_us=120.0)  # fmt: skip


def test_a_minute_of_verdicts_is_one_line_with_rate_states_delivery_and_faults(
    caplog: pytest.LogCaptureFixture,
) -> None:
    wall, mono = Clock(), Clock()
    reg = CellRegistry(None, clock=wall)
    health = HealthLog(reg, {"c1": 500.0}, interval_s=60.0, clock=mono)
    caplog.set_level(logging.INFO, logger="sara_app.health")
    _feed(reg, _status(wall.t), "sara/c1/status", wall.t)
    _feed(reg, _controller(0, wall.t, 0, 0, {}), "sara/c1/controller/status", wall.t)
    health.poll()  # the first poll: the worker's state
    assert "c1: worker running (scenario punches)" in caplog.text
    caplog.clear()
    n = 0
    for k in range(30_000):  # one minute at 500 Hz: 3 % braking, 20 fault verdicts at the end
        wall.t += 0.002
        mode = "failsafe" if k % 100 < 3 else "intended"
        faults = ["human 'p1': l_wrist speed 9.10 > bound 6.00"] if k >= 29_980 else []
        _feed(reg, _verdict(k, wall.t, mode, faults=faults), "sara/c1/verdict", wall.t)
        n += 1
        if k == 0:
            health.poll()  # the first verdict seen: the rate counts from here
        if k % 500 == 0:
            _feed(reg, _status(wall.t), "sara/c1/status", wall.t)
    _feed(reg, _controller(1, wall.t, 29_990, 2, {"worker": 2}), "sara/c1/controller/status",
          wall.t)  # fmt: skip
    mono.t += 59.0
    health.poll()  # the fault is a state change, said at once
    assert "c1: fault: human 'p1': l_wrist speed 9.10 > bound 6.00" in caplog.text
    mono.t += 1.0
    caplog.clear()
    health.poll()
    (line,) = [r.getMessage() for r in caplog.records]
    assert line.startswith("c1: 500 verdicts/s (100.0 % of 500 Hz)"), line
    assert "cycle p50 110 us" in line and "skeleton age at decision p50 4.1 ms" in line
    assert "moving 97 %, braking 3 %" in line and "fault 0 %" in line
    assert ("controller: 29990 commands, 0 lost, 3 late, 2 expired, braked on its own 2 times "
            "(the worker's command came too late: 2)") in line  # fmt: skip
    assert "faults: 20 verdicts, the last: human 'p1'" in line
    # the next minute: only what happened in it
    for k in range(n, n + 100):
        wall.t += 0.002
        _feed(reg, _verdict(k, wall.t), "sara/c1/verdict", wall.t)
    _feed(reg, _status(wall.t), "sara/c1/status", wall.t)
    mono.t += 60.0
    caplog.clear()
    health.poll()
    text = caplog.text
    assert "fault cleared" in text and "2 verdicts/s (0.3 % of 500 Hz)" in text
    assert "controller: 0 commands" in text and "faults: none" in text
    assert "reading commands late" not in text
    # a controller whose wait for commands failed says so in the next minute's line
    _feed(reg, _controller(2, wall.t, 30_100, 2, {"worker": 2}, receive_failed=True),
          "sara/c1/controller/status", wall.t)  # fmt: skip
    for k in range(n + 100, n + 200):
        wall.t += 0.002
        _feed(reg, _verdict(k, wall.t), "sara/c1/verdict", wall.t)
    mono.t += 60.0
    caplog.clear()
    health.poll()
    assert "reading commands late (its wait for them failed: restart it)" in caplog.text


def test_a_cell_going_offline_is_said_once() -> None:
    wall, mono = Clock(), Clock()
    reg = CellRegistry(None, clock=wall)
    health = HealthLog(reg, {"c1": 500.0}, clock=mono)
    said: list[str] = []
    handler = logging.Handler()
    handler.emit = lambda r: said.append(r.getMessage())  # type: ignore[method-assign]
    logging.getLogger("sara_app.health").addHandler(handler)
    logging.getLogger("sara_app.health").setLevel(logging.INFO)
    try:
        _feed(reg, _status(wall.t), "sara/c1/status", wall.t)
        _feed(reg, _verdict(0, wall.t), "sara/c1/verdict", wall.t)
        health.poll()
        for _ in range(5):
            wall.t += 3.0  # nothing for 3 s, then 6 s ...
            health.poll()
    finally:
        logging.getLogger("sara_app.health").removeHandler(handler)
    assert said[0] == "c1: worker running (scenario punches)"
    assert said[1:] == ["c1: offline: no fresh verdict (the robot's controller brakes on its own)"]


def test_percentiles_of_a_histogram_never_understate() -> None:
    rng = np.random.default_rng(0)
    samples = rng.exponential(0.005, 5000)
    c = VerdictCounters()
    for s in samples:
        c.age[min(int(s / AGE_BIN_S), len(c.age) - 1)] += 1
    for q in (50, 99):
        got = percentile_s(c.age, q, AGE_BIN_S)
        assert (
            got is not None
            and np.percentile(samples, q) <= got <= np.percentile(samples, q) + AGE_BIN_S
        )
    assert percentile_s(np.zeros(10, np.int64), 50, AGE_BIN_S) is None


def test_a_watched_machine_gets_a_line_of_its_own_stalls_each_minute(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """``serve --watch-machine``: each minute, the stalls the witnesses reported since the last
    line (what a controller that braked on its own may have met); none, said too; a witness
    that ended is said, never read as a CPU without stalls."""
    wall, mono = Clock(), Clock()
    reg = CellRegistry(None, clock=wall)

    class Watch:
        reported = [[Stall(1, 5.0, 0.0057), Stall(0, 7.0, 0.0013)], [], [Stall(0, 9.0, 0.002)]]
        gone = [[], [], [1]]

        def take(self) -> list[Stall]:
            return self.reported.pop(0)

        def ended(self) -> list[int]:
            return self.gone.pop(0)

    health = HealthLog(reg, {"c1": 500.0}, clock=mono, machine=Watch())
    caplog.set_level(logging.INFO, logger="sara_app.health")
    for expected in (
        "machine: 2 stalls of over 1 ms on its CPUs, the longest 5.7 ms in the last 60 s "
        "(CPU 0: 1, CPU 1: 1)",
        "machine: no stall of over 1 ms on any CPU in the last 60 s",
        "machine: NOT WATCHED on CPU 1 (its witness ended); 1 stall of over 1 ms on its CPUs, "
        "the longest 2.0 ms in the last 60 s (CPU 0: 1)",
    ):
        mono.t += 60.0
        caplog.clear()
        health.poll()
        assert [r.getMessage() for r in caplog.records][-1] == expected
    unwatched = HealthLog(reg, {"c1": 500.0}, clock=mono)
    mono.t += 60.0
    caplog.clear()
    unwatched.poll()
    assert not any(r.getMessage().startswith("machine:") for r in caplog.records)
