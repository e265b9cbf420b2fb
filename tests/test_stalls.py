"""The witnesses of the machine's own stalls (sara_app.ops.stalls), which ``serve
--watch-machine``, ``sara-app bench --machine`` and ``--live`` report and the reruns of
tests/conftest.py read: real witness processes, stopped for a while as a host stops a virtual
CPU, report a stall of about that length at that moment and on that CPU, as they come; a
machine that refuses real-time scheduling is said to, not witnessed by a witness that would
wait behind the cell; each exits cleanly when told to."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time

import pytest

from sara_app.ops import stalls
from sara_app.ops.stalls import Stall, Witnesses, summary

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
        "from sara_app.ops.stalls import Witnesses, summary\n"
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


def test_the_stalls_are_taken_as_they_come_while_the_witnesses_run() -> None:
    """What a health line reads each minute: the stalls since the last take, while the
    witnesses go on (a take does not wait for them to stop)."""
    w = Witnesses()
    if w.refused is not None:
        pytest.skip(f"this machine refuses SCHED_FIFO: {w.refused}")
    try:
        w.take()  # whatever the machine did so far
        cpu, held = w._procs[0]  # noqa: SLF001 - which witness to hold is the test
        _hold(held.pid, 0.03)
        taken: list[Stall] = []
        t_end = time.monotonic() + 5.0
        while not any(s.late_s > 0.02 for s in taken) and time.monotonic() < t_end:
            taken += w.take()
            time.sleep(0.01)
        assert any(s.cpu == cpu and 0.02 < s.late_s < 0.3 for s in taken), taken
        assert all(p.poll() is None for _, p in w._procs)  # noqa: SLF001 - still running
        assert not any(s.late_s > 0.02 for s in w.take())  # taken once
    finally:
        seen = w.stop()
    assert any(s.late_s > 0.02 for s in seen)  # stop() still returns what was taken


def test_a_witness_that_ended_is_named() -> None:
    """A witness killed while the others run (out of memory, a user's kill): its CPU is named,
    so that no count of stalls reads as that CPU having none."""
    w = Witnesses()
    if w.refused is not None:
        pytest.skip(f"this machine refuses SCHED_FIFO: {w.refused}")
    try:
        assert w.ended() == []
        cpu, proc = w._procs[-1]  # noqa: SLF001 - which witness to kill is the test
        proc.kill()
        proc.wait(timeout=10)
        assert w.ended() == [cpu]
    finally:
        w.stop()
