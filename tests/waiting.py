"""Waiting in tests for something a real process or server does in its own time."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path
from typing import Any


def wait_until(
    cond: Callable[[], Any],
    timeout_s: float = 10.0,
    what: str = "the condition",
    every_s: float = 0.02,
    tolerate: tuple[type[BaseException], ...] = (),
) -> Any:
    """Poll ``cond`` every ``every_s`` until it returns something true, and return that; fail
    after ``timeout_s`` naming ``what``. Exceptions of the types in ``tolerate`` (a server not
    listening yet) count as not yet."""
    t_end = time.monotonic() + timeout_s
    while True:
        try:
            got = cond()
        except tolerate:
            got = None
        if got:
            return got
        if time.monotonic() >= t_end:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        time.sleep(every_s)


def exited(pid: int) -> bool:
    """Whether process ``pid`` has exited (gone, or a zombie not yet reaped)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except (OSError, IndexError):
        return True
