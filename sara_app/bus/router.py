"""The cell's zenoh router as a process of its own (``python -m sara_app.bus.router``), so that
neither the dashboard, the API nor their clients (browsers, event streams) can delay the
messages between trackers, worker and controller: ``serve`` starts it first, supervised, at the
real-time priority of the worker where the system permits, with the cell's access control.

``--port``: the port; ``--cell`` (repeatable): the cells of the access rules;
``--credentials``: the credentials file (without it the router has no access control, as for a
development bus); ``--listen-host``: the address to listen on (default 127.0.0.1; another one
only for a deployment on several machines, docs/deployment.md); ``--print-config``: print the
router's configuration as a stand-alone ``zenohd`` file instead of running it.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading

from sara_app.bus.access import Credentials, router_access
from sara_app.bus.process import configure_logging, set_realtime
from sara_app.bus.session import Bus, router_config_dict
from sara_app.errors import SaraError
from sara_app.options import PORT, RT_PRIORITY
from sara_app.tethered import die_with_parent


def build_parser() -> argparse.ArgumentParser:
    """The router's options (module doc); numbers checked where given (:mod:`sara_app.options`)."""
    ap = argparse.ArgumentParser(prog="sara_app.bus.router", description=__doc__.splitlines()[0])
    ap.add_argument("--port", type=PORT, default=7447)
    ap.add_argument("--cell", action="append", default=[])
    ap.add_argument("--credentials", default=None)
    ap.add_argument("--rt-priority", type=RT_PRIORITY, default=0)
    ap.add_argument(
        "--die-with-parent",
        action="store_true",
        help="end when the parent process ends (serve starts it through sara_app.tethered)",
    )
    ap.add_argument("--listen-host", default="127.0.0.1")
    ap.add_argument("--print-config", action="store_true")
    return ap


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.print_config:
        access = None
        if args.credentials:
            access = router_access(args.cell or ["cell1"], Credentials(args.credentials))
        print(json.dumps(router_config_dict(args.port, args.listen_host, access), indent=2))
        return 0
    if args.die_with_parent:
        die_with_parent()
    configure_logging("router")
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        if args.rt_priority:
            set_realtime(args.rt_priority, "router", "router threads")  # zenoh's inherit it
        access = None
        if args.credentials:
            access = router_access(args.cell or ["cell1"], Credentials(args.credentials))
        with Bus.router(args.port, args.listen_host, access=access):
            logging.getLogger("sara_app.router").info(
                "listening on %s:%d", args.listen_host, args.port
            )
            stop.wait()
    except SaraError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
