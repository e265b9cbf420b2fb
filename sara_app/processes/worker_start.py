"""The cell worker's entry point as ``serve`` starts it (``python -m
sara_app.processes.worker_start``, the same arguments as ``python -m sara_app.runtime.worker``).

Importing the worker loads (and on a fresh install compiles) the safety kernels: up to a
minute before the worker could say anything. This module imports only the bus, opens a session
with the worker's credentials and publishes ``starting`` statuses (:mod:`sara_app.bus.starting`)
while the worker's modules load; then it hands over to :func:`sara_app.runtime.worker.main`, which
says ``starting`` again while it builds its cell. Without a router it just starts the worker.
``serve`` starts it through :mod:`sara_app.tethered`, which asks the kernel to end it with
``serve`` before any of this is imported.

Zenoh starts its I/O threads (``rx``, ``tx``, ``net``, ``app``) once per process, with the first
session, and every later session uses them: this early session is that first one. So it is
opened under the real-time class the worker asks for (``--rt-priority``; the threads inherit
it), and this thread goes back to normal scheduling at once (loading is no real-time work).
Opened at normal priority, it left the worker's sending and receiving threads behind any
browser on the machine: commands were lost and the robot braked on its own.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from pathlib import Path

from sara_app.bus import keys
from sara_app.bus.access import Credentials, client_auth
from sara_app.bus.process import realtime_session
from sara_app.bus.session import Bus
from sara_app.bus.starting import Starting
from sara_app.errors import SaraError
from sara_app.options import PORT, RT_PRIORITY

LOADING = "loading the worker and compiling the safety kernels"


def early_parser() -> argparse.ArgumentParser:
    """The options this module reads before the worker's own parser reads them all (numbers
    checked here too: a bad ``--rt-priority`` ended in a ValueError before the worker's check)."""
    ap = argparse.ArgumentParser(prog="sara_app.processes.worker_start", add_help=False)
    ap.add_argument("--cell", default="cell1")
    ap.add_argument("--scenario", default="standing_beside_path")
    ap.add_argument("--port", type=PORT, default=7447)
    ap.add_argument("--zenoh-user", default=None)
    ap.add_argument("--zenoh-credentials", default=None)
    ap.add_argument("--rt-priority", type=RT_PRIORITY, default=0)
    return ap


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    a = early_parser().parse_known_args(argv)[0]
    with contextlib.ExitStack() as stack:
        try:
            cell = keys.check_name("cell", a.cell)
            auth = None
            if a.zenoh_user and a.zenoh_credentials:
                auth = client_auth(a.zenoh_user, Credentials(a.zenoh_credentials))
            session, _ = realtime_session(
                a.rt_priority, "worker", lambda: Bus.client(a.port, auth=auth)
            )
            bus = stack.enter_context(session)
            pub = bus.publisher(keys.status_key(cell))
            stack.enter_context(Starting(pub, cell, Path(a.scenario).stem, LOADING))
        except (SaraError, OSError, ValueError):
            pass  # no early word: the worker reports its own errors
        from sara_app.runtime import worker  # the heavy import this module exists for

    return worker.main(argv)


if __name__ == "__main__":
    sys.exit(main())
