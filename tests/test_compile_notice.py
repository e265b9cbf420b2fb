"""The first start's compile is announced; a cached start says nothing."""

from __future__ import annotations

import io
import time

from sara_app.ops.compile_notice import WAITING, compile_notice


def test_a_slow_import_is_announced_and_its_time_reported() -> None:
    out = io.StringIO()
    with compile_notice(after_s=0.05, stream=out):
        time.sleep(0.4)
    lines = out.getvalue().splitlines()
    assert lines[0] == WAITING
    assert lines[1].startswith("kernels ready after ") and lines[1].endswith(
        " s (cached for the next start)"
    )
    assert len(lines) == 2


def test_a_fast_import_says_nothing_even_later() -> None:
    out = io.StringIO()
    with compile_notice(after_s=0.2, stream=out):
        pass
    time.sleep(0.4)  # the cancelled timer must not fire after the block
    assert out.getvalue() == ""


def test_an_import_that_fails_still_stops_the_notice() -> None:
    out = io.StringIO()
    try:
        with compile_notice(after_s=0.2, stream=out):
            raise ImportError("no module")
    except ImportError:
        pass
    time.sleep(0.4)
    assert out.getvalue() == ""
