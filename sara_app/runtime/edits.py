"""Scenario edits of a live cell worker, built off the control loop.

Building a cell can take seconds (a safety mode's compiled kernels are loaded, or compiled on a
fresh checkout): done in the control loop it would stop the commands for that long. A
``CellBuilder`` validates and builds requested scenarios in a thread of its own, one at a time,
in the order they arrived; the loop takes finished builds each cycle and swaps them in (the
robot's follower and failsafe carry over there, in the loop's thread). At most
``MAX_PENDING_EDITS`` wait; more are refused at once (the editor is told, nothing is dropped).
"""

from __future__ import annotations

import logging
import queue
import threading
from typing import NamedTuple

from sara_app.cell.build import Cell, build_cell
from sara_app.errors import SaraError
from sara_app.scenario import Scenario, check_against_robot, parse_scenario

log = logging.getLogger("sara_app.worker")
MAX_PENDING_EDITS = 16


class Built(NamedTuple):
    """A finished build: the request, and the scenario and cell, or why it failed."""

    request_id: str
    scenario: Scenario | None
    cell: Cell | None
    error: str


def build(request_id: str, data: dict) -> Built:
    """Validate ``data`` as a scenario and build its cell (never raises)."""
    try:
        sc = parse_scenario(data, "params message")
        check_against_robot(sc)
        return Built(request_id, sc, build_cell(sc), "")
    except SaraError as e:
        return Built(request_id, None, None, str(e))
    except Exception as e:  # noqa: BLE001 - a failed build is a refused edit, never a crash
        log.exception("building an edited cell failed")
        return Built(request_id, None, None, f"internal error: {e!r}")


class CellBuilder:
    """``submit(request_id, data)`` queues a build; ``done()`` returns the finished ones."""

    def __init__(self) -> None:
        self._todo: queue.Queue[tuple[str, dict] | None] = queue.Queue(MAX_PENDING_EDITS)
        self._done: queue.Queue[Built] = queue.Queue()
        self._thread: threading.Thread | None = None

    def submit(self, request_id: str, data: dict) -> bool:
        """Queue a build; False when ``MAX_PENDING_EDITS`` already wait."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="sara-cell-builder", daemon=True)
            self._thread.start()
        try:
            self._todo.put_nowait((request_id, data))
        except queue.Full:
            return False
        return True

    def done(self) -> list[Built]:
        out = []
        while True:
            try:
                out.append(self._done.get_nowait())
            except queue.Empty:
                return out

    def _run(self) -> None:
        while (item := self._todo.get()) is not None:
            self._done.put(build(*item))

    def close(self) -> None:
        if self._thread is not None:
            try:
                self._todo.put_nowait(None)
            except queue.Full:
                pass  # a daemon thread: it ends with the process
