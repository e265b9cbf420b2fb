"""``sara-app bench --machine`` (sara_app.bench.machine): the machine's own stalls as an
operator reads them before putting a cell on a machine: a row per CPU, what the host took, how
the CPUs idled; no witness left behind."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from sara_app.bench.machine import MachineStalls, report, verdict
from sara_app.ops import stalls
from sara_app.ops.stalls import Stall


def test_bench_machine_reports_every_cpu() -> None:
    cmd = [sys.executable, "-m", "sara_app", "bench", "--machine", "--seconds", "1"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=True).stdout
    lines = out.splitlines()
    assert lines[0].startswith("The machine's own stalls over 1 s"), out
    if "not witnessed" in out:
        pytest.skip(f"this machine refuses SCHED_FIFO: {lines[1]}")
    head = next(i for i, ln in enumerate(lines) if ln.split()[:2] == ["cpu", "stalls"])
    rows = [ln.split() for ln in lines[head + 1 :] if ln.split()[:1] and ln.split()[0].isdigit()]
    assert [int(r[0]) for r in rows] == sorted(os.sched_getaffinity(0)), out
    assert any("the host took at most" in ln for ln in lines)
    assert any("idle CPUs" in ln for ln in lines)
    witnesses = subprocess.run(["pgrep", "-f", stalls.__file__], capture_output=True, text=True)
    assert witnesses.stdout == "", witnesses.stdout


def test_the_report_counts_each_cpus_stalls_a_minute() -> None:
    m = MachineStalls(30.0, (0, 1), (Stall(0, 1.0, 0.0057), Stall(0, 2.0, 0.0012)), None,
                      0.0003, "idle CPUs: 100 % 'POLL'")  # fmt: skip
    lines = report(m).splitlines()
    assert lines[1].strip() == "2 stalls of over 1 ms on its CPUs, the longest 5.7 ms"
    head = next(i for i, ln in enumerate(lines) if ln.split()[:2] == ["cpu", "stalls"])
    assert lines[head + 1].split() == ["0", "2", "4.0", "5.7"]
    assert lines[head + 2].split() == ["1", "0", "0.0", "-"]
    assert "0.03 % of a CPU" in report(m)
    refused = MachineStalls(30.0, (0, 1), (), "no real-time: [Errno 1]", 0.0, "")
    assert "not witnessed: no real-time" in report(refused)
    assert not any(ln.split()[:2] == ["cpu", "stalls"] for ln in report(refused).splitlines())


def test_the_verdict_judges_the_longest_stall_against_a_period_and_a_commands_validity() -> None:
    """At 500 Hz a command is valid for 10 ms (COMMAND_VALID_MIN_S): a longer stall runs it out
    (the controller brakes on its own), a stall over a 2 ms period makes cycles late."""
    assert verdict([]).startswith("No stall longer than a 500 Hz period")
    assert verdict([Stall(0, 0.0, 0.0015)]).startswith("No stall longer")
    late = verdict([Stall(0, 0.0, 0.0015), Stall(1, 0.0, 0.0057)])
    assert late.startswith("Stalls up to 5.7 ms: longer than a period") and "(10 ms)" in late
    unfit = verdict([Stall(1, 0.0, 0.0132)])
    assert unfit.startswith("Not fit for a 500 Hz cell as it is: a stall of 13.2 ms"), unfit
    assert "will brake on its own" in unfit
    m = MachineStalls(30.0, (0,), (Stall(0, 1.0, 0.0132),), None, 0.0, "idle")
    assert report(m).splitlines()[-1].strip() == unfit
