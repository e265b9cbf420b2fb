"""``python -m sara_app.tethered MODULE [ARGS]``: run a child process's entry module (``python -m
MODULE ARGS``) tied to the process that started it, from the interpreter's first steps on.

The kernel is asked to kill this process with its parent (:func:`die_with_parent`) before
``MODULE`` is imported: a cell process's imports take a second or more on a loaded machine (the
worker's kernels up to a minute on a first start), and a ``serve`` killed meanwhile left it
importing until its own ``main`` asked (``--die-with-parent``), then noticed the parent had
changed and exited. This module imports nothing of the package, so the request comes within
milliseconds of the start. ``serve`` starts every cell process through it
(:func:`sara_app.processes.serve.spawn_cell_process`).

The kernel's signal follows the *thread* that started the process, not the process: a starter
must start children from a thread that lives as long as it does (``serve``'s main and
supervising threads), never from a request's thread that a server may end while the child runs
(the API's thread pool ends idle threads). The job runner (:mod:`sara_app.ops.jobs`) therefore
does not use it: a job writes its progress to a pipe of its owner and ends at its next line
once the owner is gone.
"""

from __future__ import annotations

import os
import runpy
import signal
import sys
from collections.abc import Mapping

LAUNCHER = "sara_app.tethered"

PARENT_PID_ENV = "SARA_APP_PARENT_PID"
"""The process id of the process that started this one (set by
:func:`~sara_app.processes.serve.start_process`): :func:`die_with_parent` compares it with the
parent it finds."""


def die_with_parent() -> None:
    """Have the kernel kill this process (SIGKILL) when its parent dies (Linux
    ``PR_SET_PDEATHSIG``), so a cell process never outlives ``serve``, even after ``kill -9``
    of it; exits at once when the parent is already gone. Elsewhere: nothing.

    The parent can die between this process's start and the request: the process is then an
    orphan, adopted by process 1 or by a subreaper (``systemd --user`` on a desktop), and the
    kernel will never signal it. So the parent its starter named (:data:`PARENT_PID_ENV`) must
    still be the parent once the request holds; without that name, a parent of 1 is taken as
    gone. A second call (the module's own ``main`` after this launcher's) repeats the request
    and finds the name already taken: only a parent of 1 counts then, and the first request
    holds anyway."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        return
    named = os.environ.pop(PARENT_PID_ENV, "")  # this process's, not its own children's
    parent = os.getppid()  # after the request: a parent that dies from now on is signalled
    if parent == 1 or (named.isdigit() and parent != int(named)):
        os._exit(0)  # the parent died before the request took effect


def command(module: str, *args: str) -> list[str]:
    """The command line that runs ``python -m module args`` tethered to its starter (which
    names itself in the child's :data:`PARENT_PID_ENV`: :func:`environment`)."""
    return [sys.executable, "-m", LAUNCHER, module, *args]


def environment(base: Mapping[str, str] | None = None) -> dict[str, str]:
    """``base`` (default: this process's environment) naming this process as the parent."""
    return {**(os.environ if base is None else base), PARENT_PID_ENV: str(os.getpid())}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0].startswith("-"):
        print(f"usage: python -m {LAUNCHER} MODULE [ARGS]", file=sys.stderr)
        return 2
    module, args = argv[0], argv[1:]
    die_with_parent()  # before the module's imports: the point of this launcher
    sys.argv = [module, *args]
    runpy.run_module(module, run_name="__main__", alter_sys=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
