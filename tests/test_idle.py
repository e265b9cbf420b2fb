"""How the CPUs idled (sara_app.ops.idle): the cpuidle counters read as the kernel lays them
out, and on this machine, what a PM QoS latency request of 0 does to them."""

from __future__ import annotations

import os
import struct
import time
from pathlib import Path

import pytest

from sara_app.errors import AccessError
from sara_app.ops.idle import (
    CPU_ROOT,
    QOS_DEVICE,
    describe,
    idle_driver,
    idle_polling,
    idle_shares,
    idle_times_us,
)


def _state(root: Path, cpu: int, k: int, name: str, time_us: int) -> None:
    d = root / f"cpu{cpu}" / "cpuidle" / f"state{k}"
    d.mkdir(parents=True, exist_ok=True)
    (d / "name").write_text(name + "\n")
    (d / "time").write_text(f"{time_us}\n")


def test_the_states_are_summed_over_cpus_by_name(tmp_path: Path) -> None:
    for cpu, (poll, halt) in enumerate(((100, 9_000), (300, 5_000))):
        _state(tmp_path, cpu, 0, "POLL", poll)
        _state(tmp_path, cpu, 1, "haltpoll idle", halt)
    (tmp_path / "cpufreq").mkdir()  # not a CPU
    before = idle_times_us(tmp_path)
    assert before == {"POLL": 400, "haltpoll idle": 14_000}
    _state(tmp_path, 0, 0, "POLL", 100 + 3_000)
    _state(tmp_path, 1, 1, "haltpoll idle", 5_000 + 1_000)
    shares = idle_shares(before, idle_times_us(tmp_path))
    assert shares == pytest.approx({"POLL": 0.75, "haltpoll idle": 0.25})
    line = describe(shares, "haltpoll")
    assert line.index("75 % 'POLL'") < line.index("25 % 'haltpoll idle'") and "haltpoll" in line


def test_no_states_no_idle_time_and_no_driver_are_said(tmp_path: Path) -> None:
    assert idle_times_us(tmp_path) == {}
    assert idle_shares({"POLL": 5}, {"POLL": 5}) == {}
    assert idle_driver(tmp_path) == "none"
    assert "no cpuidle states" in describe({}, "none")


@pytest.mark.exclusive
def test_a_latency_request_of_zero_makes_the_idle_cpus_poll() -> None:
    """This machine's counters: while a PM QoS request of 0 us is held
    (``/dev/cpu_dma_latency``, root only) the idle time is spent in 'POLL', and less of it
    once the request is gone."""
    if "POLL" not in idle_times_us():
        pytest.skip(f"no cpuidle polling state under {CPU_ROOT}")
    if not os.access(QOS_DEVICE, os.W_OK):
        pytest.skip(f"no CPU latency request allowed here ({QOS_DEVICE})")
    with idle_polling():
        time.sleep(0.05)  # the CPUs leave the states they were in
        before = idle_times_us()
        time.sleep(0.5)
        held = idle_shares(before, idle_times_us())
    time.sleep(0.05)  # the request ended with its file
    before = idle_times_us()
    time.sleep(0.5)
    free = idle_shares(before, idle_times_us())
    assert held.get("POLL", 0.0) > 0.9, held
    if len(free) > 1:  # a machine whose only state is POLL has nothing deeper to show
        assert free.get("POLL", 0.0) < held["POLL"], (free, held)  # this one: 0 % polling


def test_a_request_that_cannot_be_made_says_why(tmp_path: Path) -> None:
    with pytest.raises(AccessError, match="cannot request polling idle CPUs") as e:
        with idle_polling(tmp_path / "no_such_device"):
            pass
    assert "no_such_device" in str(e.value)


def test_the_period_tests_hold_the_latency_request(idle_cpus_poll: bool) -> None:
    """The fixture the period tests use (conftest.py) holds a request of 0 us where it can be
    made, read back from the kernel (its value is the smallest request held), and says so."""
    if not idle_cpus_poll:
        assert not os.access(QOS_DEVICE, os.W_OK)
        return
    with open(QOS_DEVICE, "rb") as f:
        assert struct.unpack("i", f.read(4)) == (0,)
