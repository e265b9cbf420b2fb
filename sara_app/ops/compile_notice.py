"""A word on the terminal while the verification kernels compile.

numba compiles the package's kernels when their modules are first imported after an install or
an upgrade (about 75 s for ``sara-app serve`` on a 2-core machine) and caches them; later
imports load the cache (``sara-app serve``: 2.3-2.6 s on that machine). Without a word the
first ``sara-app serve`` of the README prints nothing for over a minute and looks hung.
:func:`compile_notice` says what is happening when an import takes far longer than a cached
one (8 s: three times the warm import, so a loaded machine does not print it on every start),
and how long it took.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TextIO

WAITING = (
    "loading the verification kernels: the first start after an install or an upgrade "
    "compiles them (a minute or two); later starts take seconds ..."
)


@contextmanager
def compile_notice(after_s: float = 8.0, stream: TextIO | None = None) -> Iterator[None]:
    """Around the imports of a command: if they are still running after ``after_s`` seconds,
    :data:`WAITING` is written to ``stream`` (default stderr), and when they end, how long they
    took. Nothing is written when they end sooner (cached kernels)."""
    out = sys.stderr if stream is None else stream
    started = time.monotonic()
    said = threading.Event()

    def say() -> None:
        print(WAITING, file=out, flush=True)
        said.set()

    timer = threading.Timer(after_s, say)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
        timer.join()
        if said.is_set():
            took = time.monotonic() - started
            print(f"kernels ready after {took:.0f} s (cached for the next start)", file=out,
                  flush=True)  # fmt: skip
