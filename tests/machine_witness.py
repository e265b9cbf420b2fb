"""A witness of the machine's own stalls on one CPU, for the reruns of tests/conftest.py (run as
a script: ``python machine_witness.py CPU``).

Pinned to ``CPU`` under ``SCHED_FIFO`` at :data:`PRIORITY`, above every thread of the cell (its
processes ask for 10), it sleeps :data:`PERIOD_S` at a time. A wake-up more than
:data:`STALL_S` late was held up by nothing of the cell's user space, which never runs ahead of
it: by the machine (the host that ran the virtual CPU late, or the kernel, which preempts no
kernel code on a ``PREEMPT_NONE`` build). On the Intel Xeon VM of 2026-12-05, idle CPUs polling,
a thread like this one alone on the machine woke 2-6 ms late 2-8 times a minute, on either CPU,
while the kernel's steal counter moved by 0.07 % of a CPU
(docs/measurements/2026-12-05-unseen-stalls.md).

Prints ``ready`` once it runs as asked (``no real-time: ...`` and exits 3 where the class is
refused: then it would wait behind the cell and witness the cell's load, not the machine), then
one line ``<wall time s> <late s>`` per stall (at most :data:`MAX_LINES`); it exits on SIGTERM
or when its parent has gone."""

from __future__ import annotations

import os
import signal
import sys
import time

PRIORITY = 80
PERIOD_S = 0.002
"""A stall of at least a period is seen whenever it comes (a wake-up falls into it); the
witness's own share of its CPU: about 1 % (a wake-up costs a few µs)."""
STALL_S = 0.001
"""The wake-ups of a thread like this one on a polling CPU are 0.10-0.14 ms late at p99
(docs/measurements/2026-12-02-test-machine-stalls.md)."""
MAX_LINES = 1000


def main(cpu: int) -> int:
    os.sched_setaffinity(0, {cpu})
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(PRIORITY))
    except OSError as e:
        print(f"no real-time: {e}", flush=True)
        return 3
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    parent = os.getppid()
    print("ready", flush=True)
    next_s = time.monotonic()
    lines = 0
    while True:
        next_s += PERIOD_S
        time.sleep(max(next_s - time.monotonic(), 0.0))
        late_s = time.monotonic() - next_s
        if late_s > STALL_S:
            if lines < MAX_LINES:
                print(f"{time.time() - late_s:.4f} {late_s:.4f}", flush=True)
                lines += 1
            next_s = time.monotonic()  # one stall, one line: the schedule starts again
        if int(next_s) != int(next_s - PERIOD_S) and os.getppid() != parent:
            return 0  # the parent has gone (checked once a second)


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1])))
