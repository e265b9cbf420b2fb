"""The witness of the machine's stalls that the reruns of tests/conftest.py read
(tests/machine_witness.py): a real witness process, stopped for a while as a host stops a
virtual CPU, reports a stall of about that length at that moment, and exits cleanly when told
to stop."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

WITNESS = Path(__file__).parent / "machine_witness.py"


def test_a_cpu_held_from_the_witness_is_a_stall_of_that_length() -> None:
    cpu = min(os.sched_getaffinity(0))
    proc = subprocess.Popen([sys.executable, "-I", "-S", str(WITNESS), str(cpu)],
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stdout is not None
        first = proc.stdout.readline().strip()
        if first.startswith("no real-time"):
            assert proc.wait(timeout=10) == 3
            pytest.skip(f"this machine refuses SCHED_FIFO: {first}")
        assert first == "ready"
        time.sleep(0.1)
        t0 = time.time()
        os.kill(proc.pid, signal.SIGSTOP)  # as a host holds a virtual CPU
        time.sleep(0.05)
        os.kill(proc.pid, signal.SIGCONT)
        time.sleep(0.1)
    finally:
        proc.terminate()
    out, _ = proc.communicate(timeout=10)
    assert proc.returncode == 0
    stalls = [tuple(map(float, line.split())) for line in out.splitlines()]
    # the longest stall is the stop: about 50 ms, starting when it did (the machine may add its
    # own shorter ones)
    start_s, late_s = max(stalls, key=lambda s: s[1])
    assert 0.04 < late_s < 0.5, stalls
    assert abs(start_s - t0) < 0.02, (start_s, t0)
