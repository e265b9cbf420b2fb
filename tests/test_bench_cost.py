"""``sara-app bench --live`` (sara_app.bench.cost): its accounting, checked against what it
measures, not timed (the numbers live in docs/performance.md)."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import numpy as np

from sara_app.bench.cost import (
    PROCESSES,
    LoadCost,
    ProcessCost,
    _cpu_s,
    _latencies,
    _published_latencies,
    _switches,
    _zenoh_cpu_s,
    report,
    scenario_with_people,
)
from sara_app.bus.messages import VerdictMsg
from sara_app.bus.session import Bus, free_port
from sara_app.ops.stalls import Stall
from sara_app.scenario import load_scenario


def test_cpu_time_and_switches_count_every_thread_of_a_process() -> None:
    """A busy thread's CPU shows in the process's total; a thread that sleeps 50 times
    switches at least 50 times (counted while it lives: the cell's threads live as long as
    their process)."""
    pid = os.getpid()
    cpu0, sw0 = _cpu_s(pid), _switches(pid)
    napped, done = threading.Event(), threading.Event()

    def spin() -> None:
        t_end = time.process_time() + 0.3
        while time.process_time() < t_end:
            pass

    def nap() -> None:
        for _ in range(50):
            time.sleep(0.001)
        napped.set()
        done.wait(10)

    threads = [threading.Thread(target=spin), threading.Thread(target=nap)]
    for t in threads:
        t.start()
    napped.wait(10)
    switches = _switches(pid) - sw0
    done.set()
    for t in threads:
        t.join()
    assert _cpu_s(pid) - cpu0 >= 0.25
    assert switches >= 50


def test_zenoh_threads_are_told_from_python() -> None:
    """Traffic through real zenoh sessions in this process makes its zenoh threads spend CPU;
    a Python thread spinning on its own adds to the total, not to zenoh's share."""
    pid = os.getpid()
    port = free_port()
    with Bus.router(port), Bus.client(port) as a, Bus.client(port) as b:
        sub = b.subscribe("sara/zc/**")
        pub = a.session.declare_publisher("sara/zc/x")
        zenoh0 = _zenoh_cpu_s(pid)
        for i in range(20000):
            pub.put(b"%d" % i)
        time.sleep(0.5)
        busy = _zenoh_cpu_s(pid) - zenoh0
        sub.close()
        pub.undeclare()
    zenoh0, cpu0 = _zenoh_cpu_s(pid), _cpu_s(pid)
    t_end = time.process_time() + 0.3
    while time.process_time() < t_end:
        pass
    assert busy > 0.0
    assert _cpu_s(pid) - cpu0 >= 0.25 and _zenoh_cpu_s(pid) - zenoh0 < 0.1


def _verdict(stamp: float, ages: dict[str, float]) -> VerdictMsg:
    return VerdictMsg(seq=0, stamp_s=stamp, cell="c", safety_mode="ssm", mode="intended",
                      cycle_time_us=1.0, skeleton_age_s=ages)  # fmt: skip


def test_latency_is_publication_to_the_first_verdict_that_used_the_skeleton() -> None:
    """Skeletons stamped 10.000 and 10.008 s; verdicts every 2 ms use the newest one: each
    skeleton counts once, from the first verdict received that used it."""
    got = []
    for k in range(8):
        stamp = 10.001 + 0.002 * k
        skel = 10.000 if stamp < 10.008 else 10.008
        v = _verdict(stamp, {"p1": stamp - skel})
        got.append((stamp + 0.0005, v.stamp_s, v.skeleton_age_s))
    lat = _latencies(got)
    # 10.0015 - 10.000, 10.0095 - 10.008: the cycles at 10.001 and 10.009, received 0.5 ms on
    np.testing.assert_allclose(lat, [[1000.0, 500.0], [1000.0, 500.0]], atol=1e-3)


def test_latency_from_publication_takes_each_skeletons_own_publication_time() -> None:
    """The same verdicts, the skeletons published 0.3 and 0.4 ms after their stamps: per
    skeleton, stamp -> publication and publication -> the first verdict received that used it;
    a skeleton whose publication was not heard is left out."""
    got = []
    for k in range(8):
        stamp = 10.001 + 0.002 * k
        skel = 10.000 if stamp < 10.008 else 10.008
        got.append((stamp + 0.0005, stamp, {"p1": stamp - skel, "p2": stamp - skel}))
    published = {("p1", 10.000): 10.0003, ("p1", 10.008): 10.0084}
    lat = _published_latencies(got, published)
    np.testing.assert_allclose(lat, [[300.0, 1200.0], [400.0, 1100.0]], atol=1e-3)


def test_the_loads_copy_the_first_person_to_their_own_spots(tmp_path: Path) -> None:
    path = scenario_with_people("punches", 4, tmp_path)
    sc = load_scenario(str(path))
    assert [h.id for h in sc.humans] == ["p1", "p2", "p3", "p4"]
    spots = {tuple(h.position_m) for h in sc.humans}  # type: ignore[union-attr]
    assert len(spots) == 4


def _two_runs() -> LoadCost:
    load = LoadCost(1, "punches", 500.0)
    for k, name in enumerate(PROCESSES):
        load.per_process[name] += [ProcessCost(100.0 * (k + 1), 5.0, 10.0),
                                   ProcessCost(100.0 * (k + 1) + 20, 5.0, 10.0)]  # fmt: skip
    load.verdict_hz = [500.0, 499.0]
    return load


def test_the_report_adds_the_processes_and_says_how_the_cpus_idled() -> None:
    """Two runs: each process's median and runs, the cell's total per run, and the idle
    states' median shares (a state one run did not use counts as 0 there)."""
    load = _two_runs()
    load.idle = [{"POLL": 0.2, "C1": 0.8}, {"POLL": 0.4, "C1": 0.5, "C6": 0.1}]
    load.idle_driver = "intel_idle"
    lines = report([load]).splitlines()
    total = next(ln for ln in lines if ln.split()[:1] == ["all"])
    assert total.split()[1:4] == ["1040", "1000", "1080"], total
    idle = next(ln for ln in lines if "idle CPUs" in ln)
    assert "65 % 'C1'" in idle and "30 % 'POLL'" in idle and "5 % 'C6'" in idle, idle
    assert "intel_idle" in idle
    assert not any("the machine:" in ln for ln in lines)  # no run witnessed anything


def test_the_report_says_what_the_machine_stalled_over_all_runs() -> None:
    load = _two_runs()
    load.stalls = [[Stall(0, 1.0, 0.0021)], [Stall(1, 5.0, 0.0057), Stall(0, 6.0, 0.0013)]]
    line = next(ln for ln in report([load]).splitlines() if "the machine:" in ln)
    assert "3 stalls of over 1 ms on its CPUs, the longest 5.7 ms (all runs)" in line, line
    load.stalls, load.stalls_refused = [[], []], "no real-time: [Errno 1] Operation not permitted"
    line = next(ln for ln in report([load]).splitlines() if "the machine:" in ln)
    assert "not witnessed: no real-time" in line, line
