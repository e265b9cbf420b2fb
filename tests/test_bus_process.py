"""The process helpers of sara_app.bus.process: the heap a loop starts with is frozen, so the
collector's full passes do not traverse it (in a subprocess: freezing is process-wide); a
repeated warning is summarised. (A cell process's tie to its parent: tests/test_tethered.py.)"""

from __future__ import annotations

import subprocess
import sys
import textwrap


def test_the_heap_built_before_the_loop_is_frozen() -> None:
    """After ``freeze_heap`` every object the process built (the cell, numba's and
    pinocchio's objects) is in the permanent generation: a full collection then traverses
    only what the loop allocated since (here nothing: fewer than 1 % of the objects)."""
    code = textwrap.dedent(
        """
        import gc
        from sara_app.bus.process import freeze_heap
        from sara_app.cell.build import build_cell
        from sara_app.scenario import load_scenario

        cell = build_cell(load_scenario("standing_beside_path"))
        before = len(gc.get_objects())
        frozen = freeze_heap("test")
        after = len(gc.get_objects())  # the objects a collection would traverse
        print(before, frozen, after)
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    before, frozen, after = (int(x) for x in out.stdout.split())
    assert before > 50_000 and frozen >= 0.5 * before  # the rest was garbage, collected
    assert after < 0.01 * before


def test_a_repeated_warning_is_summarised_not_a_line_each(caplog) -> None:
    """Said once when it first happens, then one line a minute with the count: 2 048 expiries
    a minute must not be 2 048 lines (issue: 175 re-anchor lines in 12 minutes)."""
    import logging

    from sara_app.bus.process import SummarisedWarning

    now = [0.0]
    warn = SummarisedWarning(logging.getLogger("sara_app.test"), "commands expired",
                             clock=lambda: now[0])  # fmt: skip
    with caplog.at_level(logging.WARNING, logger="sara_app.test"):
        for _ in range(2048):  # 500 Hz for 4 s
            warn("braking")
            now[0] += 0.002
        assert len(caplog.records) == 1 and "commands expired: braking" in caplog.text
        now[0] = 60.0
        warn("braking")
        assert len(caplog.records) == 2
        assert "commands expired 2048 times in the last 60 s (2049 in all)" in caplog.text
