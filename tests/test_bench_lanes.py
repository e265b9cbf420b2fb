"""``sara-app bench --lanes`` (``sara_app.bench.lanes``): the worker's cycle on real zenoh
sessions through a real router on 127.0.0.1, in one priority and in lanes. What a loaded
machine loses is measured there, not asserted here (it is the scheduler's); here: the lanes
mode publishes exactly as the worker does, the counts add up, the report shows them all."""

from __future__ import annotations

import subprocess
import sys

import pytest
import zenoh

from sara_app.bench.lanes import CYCLE_KINDS, MODES, _publishers, bench_lanes, report
from sara_app.bus import keys
from sara_app.bus.session import Bus, free_port, priority_of
from sara_app.errors import ParameterError


def test_each_mode_publishes_the_cycle_as_declared() -> None:
    with Bus.router(free_port()) as bus:
        flat = _publishers(bus, "c1", lanes=False)
        lanes = _publishers(bus, "c1", lanes=True)
        got = {
            lane: [(kind, str(p.key_expr), str(p.priority), str(p.congestion_control))
                   for kind, p, _ in pubs]
            for lane, pubs in (("flat", flat), ("lanes", lanes))
        }  # fmt: skip
        for _, p, payload in flat + lanes:
            assert payload[:1] == b"{"  # the contract's JSON
            p.undeclare()
    drop = str(zenoh.CongestionControl.DROP)
    assert got["flat"] == [
        (k, keys.key(k, "c1"), str(zenoh.Priority.DATA), drop) for k in CYCLE_KINDS
    ]
    assert got["lanes"] == [
        (k, keys.key(k, "c1"), str(priority_of(keys.key(k, "c1"))), drop) for k in CYCLE_KINDS
    ]
    assert len({prio for _, _, prio, _ in got["lanes"]}) == 4  # command, answer, display apart
    assert set(keys.BATCHED_KINDS) <= set(CYCLE_KINDS)


def test_losses_are_counted_per_kind_and_reported() -> None:
    rounds = 40
    losses = bench_lanes(rounds=rounds, period_s=0.002, hogs=0, runs=1)
    assert set(losses) == set(MODES)
    for mode in MODES:
        (run,) = losses[mode]
        assert set(run.lost) == set(CYCLE_KINDS)
        assert all(0 <= n <= rounds for n in run.lost.values()), run
        assert 0.0 < run.puts_p99_us < 2e6
        assert 0 <= run.commands_late <= rounds - run.lost["robot_command"], run  # arrived
    text = report(losses, rounds, 0)
    assert f"of {rounds} per key" in text
    rows = {line.split()[0]: line for line in text.splitlines()[3:]}
    assert set(rows) == {*CYCLE_KINDS, "commands", "puts"}
    assert rows["robot_command"].split()[1:] == [str(losses[m][0].lost["robot_command"])
                                                 for m in MODES]  # fmt: skip
    assert rows["commands"].split()[2:] == [str(losses[m][0].commands_late) for m in MODES]


def test_the_command_line_runs_it() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "sara_app", "bench", "--lanes", "--lane-rounds", "20",
         "--runs", "1", "--hogs", "1"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert "1 busy process beside" in proc.stdout
    rows = [line.split() for line in proc.stdout.splitlines()[3:]]
    assert [r[0] for r in rows] == [*CYCLE_KINDS, "commands", "puts"]


@pytest.mark.parametrize("bad", [{"rounds": 0}, {"runs": 0}, {"hogs": -1}, {"period_s": -1.0}])
def test_nonsense_is_refused_before_anything_starts(bad: dict) -> None:
    with pytest.raises(ParameterError, match="expected rounds and runs >= 1"):
        bench_lanes(**bad)
