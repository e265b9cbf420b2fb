"""sara_app.tethered: a cell process never outlives the process that started it, from its
first steps on (``python -m sara_app.tethered MODULE``), also when that process dies while it
starts and a subreaper adopts it."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time

import pytest
from waiting import exited, wait_until

from sara_app.tethered import PARENT_PID_ENV


def test_the_launcher_without_a_module_says_how_it_is_used() -> None:
    for args in ([], ["--die-with-parent"]):
        out = subprocess.run([sys.executable, "-m", "sara_app.tethered", *args],
                             capture_output=True, text=True, timeout=60)  # fmt: skip
        assert out.returncode == 2 and "usage: python -m sara_app.tethered MODULE" in out.stderr


def test_the_launcher_runs_the_module_as_main_with_its_arguments() -> None:
    """What ``python -m MODULE ARGS`` would do: the module's own exit status and output."""
    out = subprocess.run([sys.executable, "-m", "sara_app.tethered", "sara_app.bus.router",
                          "--port", "0"], capture_output=True, text=True, timeout=60)  # fmt: skip
    assert out.returncode == 2 and "--port" in out.stderr and "sara_app.bus.router" in out.stderr


def test_the_launcher_imports_nothing_of_the_package_before_the_request() -> None:
    """Its point: the request comes before the package's imports (0.4 s for the bus alone)."""
    code = textwrap.dedent(
        """
        import sys
        import sara_app.tethered
        print(sorted(m for m in sys.modules if m.startswith("sara_app")))
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.stdout.strip() == "['sara_app', 'sara_app.tethered']", out.stdout + out.stderr


_ARMED_CHILD = (
    "from sara_app.tethered import die_with_parent; die_with_parent(); "
    "print('armed', flush=True); import time; time.sleep(60)"
)


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
        assert not exited(child)  # a child that died meanwhile stays a zombie or gone
        proc.kill()
        proc.wait(10)
        wait_until(lambda: exited(child), 10.0, "the child's exit with its parent")
    finally:
        proc.kill()
        proc.wait(10)


_SUBREAPER = """
import ctypes, os, subprocess, sys, time
ctypes.CDLL(None).prctl(36, 1, 0, 0, 0)  # PR_SET_CHILD_SUBREAPER: orphans below come here
serve = subprocess.Popen([sys.executable, "-c", sys.argv[1]], stdout=subprocess.PIPE, text=True)
child = int(serve.stdout.readline())
maps = f"/proc/{child}/maps"
while sys.argv[2] not in open(maps).read():  # the child is importing its modules now
    time.sleep(0.01)
serve.kill()
serve.wait()
_, status = os.waitpid(child, 0)  # adopted: this process reaps it
signal = os.WIFSIGNALED(status) and os.WTERMSIG(status)
print(signal, os.WIFEXITED(status) and os.WEXITSTATUS(status))
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux's")
@pytest.mark.parametrize(
    ("module", "loading"),
    [
        ("sara_app.processes.worker_start", "llvmlite"),  # its compiled kernels
        ("sara_app.peers.controller", "numpy"),
        ("sara_app.peers.replayer", "numpy"),
    ],
)
def test_a_cell_process_whose_serve_is_killed_while_it_imports_is_killed_with_it(
    module: str, loading: str
) -> None:
    """A cell process imports for a second or more (the worker loads its kernels for up to a
    minute on a first start): a ``serve`` killed meanwhile takes it along at once (the kernel's
    SIGKILL), instead of leaving it to finish importing and only then notice (an exit status
    of 0). ``serve``'s own way of starting it (``spawn_cell_process``)."""
    serve = textwrap.dedent(
        f"""
        import time
        from sara_app.processes.serve import spawn_cell_process
        child = spawn_cell_process({module!r}, "gone1", "standing_beside_path", 9)
        print(child.pid, flush=True)
        time.sleep(120)
        """
    )
    out = subprocess.run([sys.executable, "-c", _SUBREAPER, serve, loading],
                         capture_output=True, text=True, timeout=120)  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["9", "False"], out.stdout
