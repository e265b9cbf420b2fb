"""Where serve's processes run (sara_app.processes.affinity): the plan, the command that pins a
process from its start, and moving a running process's threads."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from sara_app.processes.affinity import cpu_plan, pin_threads, pinned, placed_as_serve


def test_each_worker_gets_a_cpu_of_its_own_only_when_one_is_left_for_the_rest() -> None:
    plan = cpu_plan(1, {0, 1})
    assert plan is not None and plan.workers == (frozenset({1}),) and plan.rest == {0}
    plan = cpu_plan(2, {0, 1, 2, 3})
    assert plan is not None and plan.workers == (frozenset({2}), frozenset({3}))
    assert plan.rest == {0, 1}
    assert cpu_plan(2, {0, 1}) is None and cpu_plan(1, {5}) is None
    assert cpu_plan(1, {3, 7, 9}).workers == (frozenset({9}),)  # type: ignore[union-attr]


def _allowed(pid: int | str) -> str:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("Cpus_allowed_list:"):
            return line.split()[1]
    raise AssertionError("no Cpus_allowed_list")


@pytest.mark.skipif(shutil.which("taskset") is None, reason="no taskset")
def test_a_pinned_command_and_every_thread_it_starts_run_on_its_cpus() -> None:
    cpu = min(os.sched_getaffinity(0))
    code = ("import threading, time, os; t = threading.Thread(target=time.sleep, args=(2,)); "
            "t.start(); print(sorted(os.sched_getaffinity(0)), flush=True); t.join()")  # fmt: skip
    proc = subprocess.Popen(pinned([sys.executable, "-c", code], frozenset({cpu})),
                            stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == f"[{cpu}]"
        tasks = list(Path(f"/proc/{proc.pid}/task").iterdir())
        assert len(tasks) >= 2 and {_allowed(f"{proc.pid}/task/{t.name}") for t in tasks} == {
            str(cpu)
        }
    finally:
        proc.wait(10)
    assert pinned(["x"], None) == ["x"]


def test_a_running_process_s_threads_move_and_come_back() -> None:
    before = frozenset(os.sched_getaffinity(0))
    one = frozenset({min(before)})
    stop = threading.Event()
    t = threading.Thread(target=stop.wait)
    t.start()
    try:
        assert pin_threads(os.getpid(), one) >= 2
        assert os.sched_getaffinity(t.native_id) == one  # type: ignore[arg-type]
    finally:
        pin_threads(os.getpid(), before)
        stop.set()
        t.join()
    assert os.sched_getaffinity(0) == before


def test_a_benchmark_placed_as_serve_runs_on_the_rest_and_comes_back() -> None:
    """placed_as_serve: inside, this process's threads run on the plan's rest (where there is a
    CPU to spare), and on leaving, even by an exception, on the CPUs they had; without pinning
    nothing moves."""
    before = frozenset(os.sched_getaffinity(0))
    with pytest.raises(RuntimeError):
        with placed_as_serve(True) as plan:
            if plan is None:
                assert len(before) < 2
            else:
                assert os.sched_getaffinity(0) == plan.rest
                assert not plan.rest & plan.worker(0)
            raise RuntimeError("the benchmark failed")
    assert os.sched_getaffinity(0) == before
    with placed_as_serve(False) as plan:
        assert plan is None and os.sched_getaffinity(0) == before
