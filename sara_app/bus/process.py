"""The ``main`` of a cell process (worker, replayer): arguments, a zenoh client session, stop on
SIGINT/SIGTERM, domain errors as exit code 2."""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
from collections.abc import Callable
from typing import Protocol

from sara_app.bus.session import Bus
from sara_app.errors import SaraError
from sara_app.scenario import Scenario, load_scenario


class CellProcess(Protocol):
    stop_event: threading.Event

    def run(self, duration_s: float | None = None) -> None: ...


def process_main(
    name: str,
    description: str,
    factory: Callable[[str, Scenario, Bus], CellProcess],
    argv: list[str] | None = None,
) -> int:
    ap = argparse.ArgumentParser(prog=f"sara_app.{name}", description=description)
    ap.add_argument("--cell", default="cell1")
    ap.add_argument("--scenario", default="standing_beside_path")
    ap.add_argument("--port", type=int, default=7447, help="zenoh router port on 127.0.0.1")
    ap.add_argument("--duration", type=float, default=None)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format=f"%(asctime)s {name} %(message)s")
    try:
        sc = load_scenario(args.scenario)
        with Bus.client(args.port) as bus:
            proc = factory(args.cell, sc, bus)
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, lambda *_: proc.stop_event.set())
            proc.run(args.duration)
    except SaraError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0
