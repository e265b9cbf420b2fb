"""A cell worker running in a thread of the test process (its own zenoh session, real bus)."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from sara_app.bus.session import Bus
from sara_app.runtime.worker import CellWorker
from sara_app.scenario import Scenario


@contextmanager
def running_worker(cell: str, scenario: Scenario, bus: Bus, **kwargs: Any) -> Iterator[CellWorker]:
    """``CellWorker(cell, scenario, bus, **kwargs)`` running until the block ends."""
    worker = CellWorker(cell, scenario, bus, **kwargs)
    thread = threading.Thread(target=worker.run, daemon=True)
    thread.start()
    try:
        yield worker
    finally:
        worker.stop_event.set()
        thread.join(10)
