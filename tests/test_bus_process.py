"""The process helpers of sara_app.bus.process: the heap a loop starts with is frozen, so the
collector's full passes do not traverse it (in a subprocess: freezing is process-wide); a cell
process never outlives the process that started it."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest
from waiting import wait_until

from sara_app.bus.process import PARENT_PID_ENV


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


_ARMED_CHILD = (
    "from sara_app.bus.process import die_with_parent; die_with_parent(); "
    "print('armed', flush=True); import time; time.sleep(60)"
)


def _exited(pid: int) -> bool:
    """Whether ``pid`` has exited (gone, or a zombie not yet reaped)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] == "Z"
    except (OSError, IndexError):
        return True


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_cell_process_whose_parent_died_before_it_was_armed_exits() -> None:
    """The parent its starter named is not its parent any more (it died while the interpreter
    started, and the process was adopted by a subreaper or process 1): it exits at once instead
    of running on where no kill of ``serve`` can reach it."""
    env = {**os.environ, PARENT_PID_ENV: str(2**22 + 7)}  # no process's parent here
    out = subprocess.run([sys.executable, "-c", _ARMED_CHILD], env=env, capture_output=True,
                         text=True, timeout=50)  # fmt: skip
    assert out.returncode == 0 and "armed" not in out.stdout, (out.stdout, out.stderr)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_cell_process_dies_with_the_process_that_started_it() -> None:
    """Started as serve starts its processes (``start_process``, which names itself as the
    parent): armed, it runs while its parent lives and is gone once its parent is killed."""
    parent = textwrap.dedent(
        f"""
        import sys, time
        from sara_app.processes.serve import start_process
        child = start_process([sys.executable, "-c", {_ARMED_CHILD!r}])
        print(child.pid, flush=True)
        time.sleep(60)
        """
    )
    proc = subprocess.Popen([sys.executable, "-c", parent], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        child = int(proc.stdout.readline())
        assert proc.stdout.readline().strip() == "armed"  # the child's, on the same pipe
        time.sleep(0.5)
        assert not _exited(child)  # a child that died meanwhile stays a zombie or gone
        proc.kill()
        proc.wait(10)
        wait_until(lambda: _exited(child), 10.0, "the child's exit with its parent")
    finally:
        proc.kill()
        proc.wait(10)


_SUBREAPER = """
import ctypes, os, subprocess, sys, time
ctypes.CDLL(None).prctl(36, 1, 0, 0, 0)  # PR_SET_CHILD_SUBREAPER: orphans below come here
serve = subprocess.Popen([sys.executable, "-c", sys.argv[1]], stdout=subprocess.PIPE, text=True)
child = int(serve.stdout.readline())
maps = f"/proc/{child}/maps"
while "llvmlite" not in open(maps).read():  # the worker loads its compiled kernels now
    time.sleep(0.01)
serve.kill()
serve.wait()
_, status = os.waitpid(child, 0)  # adopted: this process reaps it
signal = os.WIFSIGNALED(status) and os.WTERMSIG(status)
print(signal, os.WIFEXITED(status) and os.WEXITSTATUS(status))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
def test_a_worker_whose_serve_is_killed_while_it_loads_is_killed_with_it() -> None:
    """``serve``'s worker entry (``processes.worker_start``) loads the kernels for up to a minute
    on a first start: a ``serve`` killed meanwhile takes it along at once (the kernel's SIGKILL),
    instead of leaving it to finish loading and only then notice (an exit status of 0)."""
    serve = textwrap.dedent(
        """
        import sys, time
        from sara_app.processes.serve import start_process
        child = start_process([sys.executable, "-m", "sara_app.processes.worker_start",
                               "--cell", "gone1", "--port", "9", "--die-with-parent"])
        print(child.pid, flush=True)
        time.sleep(120)
        """
    )
    out = subprocess.run([sys.executable, "-c", _SUBREAPER, serve], capture_output=True,
                         text=True, timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["9", "False"], out.stdout
