"""A deadline one thread sleeps on and another pushes back without waking it.

The reference controller publishes a robot state on every command it takes and, when none came
for a control period, on its own. Waking a thread every period to find that a command came in
time costs a context switch and a GIL hand-over per cycle (about 30 us of CPU on a VM). Here the
thread that takes commands re-arms the deadline after each state (one system call); the
sleeping thread wakes only when a period passed without a state, or when the deadline is
closed.

On Linux the deadline is a ``timerfd`` (CLOCK_MONOTONIC, through ctypes: ``os.timerfd_*`` only
exist from Python 3.13); elsewhere, or where it cannot be created, a condition variable whose
sleeper wakes at the old deadline and sleeps on to the new one (a wake-up per period, as a
polling loop).
"""

from __future__ import annotations

import ctypes
import math
import os
import sys
import threading
import time
from typing import Any

MIN_DELAY_S = 1e-6
"""The shortest delay armed (a zero delay would disarm a timerfd)."""


_Itimerspec = ctypes.c_long * 4
"""``struct itimerspec``: interval (s, ns), then value (s, ns)."""


def _timerfd() -> tuple[int, Any] | None:
    """A monotonic timerfd and ``timerfd_settime``, or None where there is none."""
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        fd = int(libc.timerfd_create(time.CLOCK_MONOTONIC, os.O_CLOEXEC))
        settime = libc.timerfd_settime
    except (OSError, AttributeError):
        return None
    settime.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_void_p, ctypes.c_void_p]
    settime.restype = ctypes.c_int
    return (fd, settime) if fd >= 0 else None


class Deadline:
    """``arm(delay_s)`` sets the deadline ``delay_s`` from now (replacing the previous one);
    ``wait()`` sleeps until it passes (True) or :meth:`close` is called (False). One waiting
    thread; any thread may arm or close."""

    def __init__(self, use_timerfd: bool = True) -> None:
        self._closed = False
        made = _timerfd() if use_timerfd else None
        self._fd: int = made[0] if made else -1
        self._settime: Any = made[1] if made else None
        self._spec = _Itimerspec()
        self._spec_at = ctypes.addressof(self._spec)
        self._cond = threading.Condition()
        self._at = math.inf  # the fallback's deadline (monotonic s)

    @property
    def kernel_timer(self) -> bool:
        """Whether a timerfd carries it (the sleeper does not wake when it is pushed back)."""
        return self._fd >= 0

    def arm(self, delay_s: float) -> None:
        delay = max(float(delay_s), MIN_DELAY_S) if delay_s == delay_s else MIN_DELAY_S
        if self._fd >= 0 and self._settime is not None:
            spec, sec = self._spec, int(delay)
            spec[2], spec[3] = sec, int((delay - sec) * 1e9) or (0 if sec else 1)
            self._settime(self._fd, 0, self._spec_at, None)
            return
        with self._cond:
            at = time.monotonic() + delay
            earlier = at < self._at
            self._at = at
            if earlier:
                self._cond.notify()

    def wait(self) -> bool:
        """Sleep until the deadline passes (True) or the deadline is closed (False)."""
        if self._fd >= 0:
            if not self._closed:
                try:
                    os.read(self._fd, 8)  # blocks (without the GIL) until the timer expires
                except OSError:
                    return False
            return not self._closed
        with self._cond:
            while not self._closed:
                left = self._at - time.monotonic()
                if left <= 0.0:
                    self._at = math.inf
                    return True
                self._cond.wait(None if left == math.inf else left)
            return False

    def close(self) -> None:
        """Wake the sleeper with False; later waits return False at once. The timerfd is
        closed by :meth:`release` (after the sleeper is gone)."""
        self._closed = True
        if self._fd >= 0:
            self.arm(MIN_DELAY_S)
        with self._cond:
            self._cond.notify_all()

    def release(self) -> None:
        """Close the timerfd (call once no thread waits any more)."""
        self._closed = True
        if self._fd >= 0:
            fd, self._fd = self._fd, -1
            os.close(fd)
