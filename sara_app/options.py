"""Numbers on the command line: each numeric option's type checks its value where it is given,
so a NaN, an infinity, a negative duration or an empty count is refused by argparse (naming the
option, the value and the valid range; exit status 2) before anything runs. Without this,
``run --duration nan`` ended in a ValueError, ``report --duration -1`` wrote an evidence report of
closed loops that never ran and ``adversarial --episodes -3`` printed a table of none.
Shared by ``sara-app``'s commands and the cell's own process entry points (``python -m
sara_app.bus.router``, the processes of :func:`sara_app.bus.process.process_parser`).
``tests/test_numbers.py`` checks that no option of either takes a bare ``float`` or ``int``."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable


def real(
    low: float | None = None, high: float | None = None, *, above: float | None = None
) -> Callable[[str], float]:
    """The type of an option that takes a finite number in ``[low, high]`` (``above``: strictly
    greater than it)."""
    bounds = ((">", above), (">=", low), ("<=", high))
    parts = [f"{op} {v:g}" for op, v in bounds if v is not None]
    expected = " ".join(["a finite number", " and ".join(parts)]).strip()

    def parse(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            v = math.nan
        if not (
            math.isfinite(v)
            and (above is None or v > above)
            and (low is None or v >= low)
            and (high is None or v <= high)
        ):
            raise argparse.ArgumentTypeError(f"{text!r}; expected {expected}")
        return v

    parse.__name__ = "real"
    return parse


def whole(low: int, high: int | None = None) -> Callable[[str], int]:
    """The type of an option that takes a whole number in ``[low, high]``."""
    expected = f"a whole number >= {low}" + ("" if high is None else f" and <= {high}")

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r}; expected {expected}") from None
        if v < low or (high is not None and v > high):
            raise argparse.ArgumentTypeError(f"{text!r}; expected {expected}")
        return v

    parse.__name__ = "whole"
    return parse


SECONDS = real(above=0.0)
"""A duration, a period or a horizon (s)."""
COUNT = whole(1)
"""Episodes, samples, runs, calls: at least one."""
SEED = whole(0)
"""A random seed (numpy takes none below 0)."""
PORT = whole(1, 65535)
"""A TCP port (a server of this project listens on 127.0.0.1 unless told otherwise)."""
FRACTION = real(above=0.0, high=1.0)
"""A share of a limit, (0, 1]."""
RT_PRIORITY = whole(0, 99)
"""A SCHED_FIFO priority, 1-99; 0: normal scheduling."""
