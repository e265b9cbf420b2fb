"""The witnesses of the machine's own stalls (sara_app.bench.stalls), which ``sara-app bench
--machine`` and ``--live`` report and the reruns of tests/conftest.py read: real witness
processes, stopped for a while as a host stops a virtual CPU, report a stall of about that
length at that moment and on that CPU; a machine that refuses real-time scheduling is said to,
not witnessed by a witness that would wait behind the cell; each exits cleanly when told to."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from sara_app.bench import stalls
from sara_app.bench.stalls import Stall, Witnesses, summary

WITNESS = stalls.__file__


def _start(cpu: int) -> subprocess.Popen[str]:
    proc = subprocess.Popen([sys.executable, "-I", "-S", WITNESS, str(cpu)],
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    assert proc.stdout is not None
    first = proc.stdout.readline().strip()
    if first.startswith("no real-time"):
        assert proc.wait(timeout=10) == stalls.REFUSED
        pytest.skip(f"this machine refuses SCHED_FIFO: {first}")
    assert first == "ready"
    return proc


def _hold(pid: int, seconds: float) -> float:
    """Stop a process for ``seconds`` (as a host holds a virtual CPU); when (wall s)."""
    time.sleep(0.1)
    t0 = time.time()
    os.kill(pid, signal.SIGSTOP)
    time.sleep(seconds)
    os.kill(pid, signal.SIGCONT)
    time.sleep(0.1)
    return t0


def test_a_cpu_held_from_the_witness_is_a_stall_of_that_length() -> None:
    proc = _start(min(os.sched_getaffinity(0)))
    try:
        t0 = _hold(proc.pid, 0.05)
    finally:
        proc.terminate()
    out, _ = proc.communicate(timeout=10)
    assert proc.returncode == 0
    seen = [tuple(map(float, line.split())) for line in out.splitlines()]
    # the longest stall is the stop: about 50 ms, starting when it did (the machine may add its
    # own shorter ones)
    start_s, late_s = max(seen, key=lambda s: s[1])
    assert 0.04 < late_s < 0.5, seen
    assert abs(start_s - t0) < 0.02, (start_s, t0)


def test_the_witnesses_name_the_cpu_that_stalled() -> None:
    """One witness per CPU this process may use; the one held 30 ms reports the longest stall,
    on its own CPU."""
    w = Witnesses()
    if w.refused is not None:
        pytest.skip(f"this machine refuses SCHED_FIFO: {w.refused}")
    procs = w._procs  # noqa: SLF001 - which witness to hold is the test
    try:
        assert [cpu for cpu, _ in procs] == sorted(os.sched_getaffinity(0))
        cpu, held = procs[-1]
        t0 = _hold(held.pid, 0.03)
    finally:
        seen = w.stop()
    assert all(p.returncode == 0 for _, p in procs)
    assert seen == sorted(seen, key=lambda s: s.late_s, reverse=True)
    longest = seen[0]
    assert longest.cpu == cpu and 0.02 < longest.late_s < 0.3, seen
    assert abs(longest.start_s - t0) < 0.02, (longest, t0)


@pytest.mark.skipif(shutil.which("setpriv") is None, reason="needs util-linux's setpriv")
def test_a_machine_that_refuses_real_time_is_not_witnessed_and_says_why() -> None:
    """Without CAP_SYS_NICE (and no rtprio limit) the witnesses cannot rise above a cell's
    processes: none runs, none is left behind, and the report says why."""
    code = (
        "from sara_app.bench.stalls import Witnesses, summary\n"
        "w = Witnesses()\n"
        "print(w.refused)\n"
        "print(w.stop(), w._procs)\n"
        "print(summary([], w.refused))\n"
    )
    drop = ["setpriv", "--inh-caps=-sys_nice", "--bounding-set=-sys_nice"]
    out = subprocess.run([*drop, sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60, check=True).stdout.splitlines()  # fmt: skip
    if out[0] == "None":
        pytest.skip("SCHED_FIFO allowed without CAP_SYS_NICE here (an rtprio limit)")
    assert out[0].startswith("no real-time"), out
    assert out[1] == "[] []"
    assert out[2].startswith("not witnessed: no real-time") and "rtprio" in out[2], out


def test_the_summary_counts_the_stalls_and_names_the_longest() -> None:
    seen = [Stall(0, 1.0, 0.0042), Stall(1, 2.0, 0.0011)]
    assert summary(seen, None) == "2 stalls of over 1 ms on its CPUs, the longest 4.2 ms"
    assert summary(seen[:1], None) == "1 stall of over 1 ms on its CPUs, the longest 4.2 ms"
    assert summary([], None) == "no stall of over 1 ms on any CPU"


def test_bench_machine_reports_every_cpu() -> None:
    """``sara-app bench --machine`` as an operator runs it: a row per CPU, what the host took,
    how the CPUs idled; no witness left behind."""
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
    witnesses = subprocess.run(["pgrep", "-f", WITNESS], capture_output=True, text=True)
    assert witnesses.stdout == "", witnesses.stdout
