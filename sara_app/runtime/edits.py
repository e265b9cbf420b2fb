"""Scenario edits of a live cell worker: built off the control loop, swapped in between two
cycles (never half-applied), kept on disk and announced.

Building a cell can take seconds (a safety mode's compiled kernels are loaded, or compiled on a
fresh checkout): done in the control loop it would stop the commands for that long. A
``CellBuilder`` validates and builds requested scenarios in a thread of its own, one at a time,
in the order they arrived; the loop takes finished builds each cycle and swaps them in (the
robot's follower and failsafe carry over there, in the loop's thread). At most
``MAX_PENDING_EDITS`` wait; more are refused at once (the editor is told, nothing is dropped).
:class:`LiveEdits` holds the builds, the edit revision and the cell's state on disk
(:class:`~sara_app.runtime.cell_state.CellState`: the edits survive a restart);
:func:`carry_over` moves the robot's follower and failsafe into a new cell.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from sara_app.bus.messages import ParamsMsg
from sara_app.cell.build import Cell, build_cell
from sara_app.errors import SaraError
from sara_app.ops.loosening import LooseningRefusedError, check_loosening
from sara_app.runtime.bus_io import CellBus
from sara_app.runtime.cell_state import CellState
from sara_app.scenario import Scenario, check_against_robot, parse_scenario

log = logging.getLogger("sara_app.worker")
MAX_PENDING_EDITS = 16


class Built(NamedTuple):
    """A finished build: the request, and the scenario and cell, or why it failed; whether the
    sender confirmed a loosening, and who (:class:`~sara_app.bus.messages.ParamsMsg`)."""

    request_id: str
    scenario: Scenario | None
    cell: Cell | None
    error: str
    confirm: bool = False
    user: str = ""


def build(request_id: str, data: dict, confirm: bool = False, user: str = "") -> Built:
    """Validate ``data`` as a scenario and build its cell (never raises)."""
    try:
        sc = parse_scenario(data, "params message")
        check_against_robot(sc)
        return Built(request_id, sc, build_cell(sc), "", confirm, user)
    except SaraError as e:
        return Built(request_id, None, None, str(e))
    except Exception as e:  # noqa: BLE001 - a failed build is a refused edit, never a crash
        log.exception("building an edited cell failed")
        return Built(request_id, None, None, f"internal error: {e!r}")


def unconfirmed_loosening(current: Scenario, b: Built) -> str | None:
    """Why ``b`` may not run after ``current``: it loosens what the verdict assumes and its
    sender did not confirm that (:mod:`sara_app.ops.loosening`; the API and the dashboard
    confirm and audit, any other editor on the bus must say so too); None when it may. A
    confirmed loosening is logged with who confirmed it."""
    if b.scenario is None:
        return None
    try:
        found = check_loosening(current, b.scenario, confirm=b.confirm,
                                how_to_confirm="send it with confirm: true")  # fmt: skip
    except LooseningRefusedError as e:
        return str(e)
    if found:
        log.warning("edit %s by %r loosens what the verdict assumes, confirmed: %s",
                    b.request_id, b.user or "(no user given)", "; ".join(found))  # fmt: skip
    return None


class CellBuilder:
    """``submit(request_id, data)`` queues a build; ``done()`` returns the finished ones."""

    def __init__(self) -> None:
        self._todo: queue.Queue[tuple[str, dict, bool, str] | None] = queue.Queue(MAX_PENDING_EDITS)
        self._done: queue.Queue[Built] = queue.Queue()
        self._thread: threading.Thread | None = None

    def submit(self, request_id: str, data: dict, confirm: bool = False, user: str = "") -> bool:
        """Queue a build; False when ``MAX_PENDING_EDITS`` already wait."""
        if self._thread is None:
            self._thread = threading.Thread(target=self._run, name="sara-cell-builder", daemon=True)
            self._thread.start()
        try:
            self._todo.put_nowait((request_id, data, confirm, user))
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


def carry_over(old: Cell, new: Cell) -> str | None:
    """Prepare ``new`` to run from now on with the robot's follower and the failsafe it holds
    carried over from ``old`` (verified under the old parameters: the new parameters and safety
    mode take effect from the next verified step); None, or why ``new`` cannot run now."""
    sc = new.scenario
    same_robot = sc.robot == old.scenario.robot and sc.limits == old.scenario.limits
    if not same_robot and not old.shield.at_rest:
        return "robot, base pose or limits can change only while the robot is at rest"
    if same_robot:
        try:
            new.shield.adopt(old.shield)
            if sc.task != old.scenario.task:
                new.shield.follower.replan(new.passes[0])
        except SaraError as e:
            return str(e)
    return None


class LiveEdits:
    """The edits of cell ``cell_name`` started from ``origin`` (a scenario name or file): builds
    in flight and finished, the edit ``revision`` and, with ``state_dir``, the state in force on
    disk. ``errors`` logs a failure, rate-limited."""

    def __init__(
        self,
        cell_name: str,
        origin: str,
        state_dir: str | Path | None,
        errors: Callable[..., None],
    ) -> None:
        self.origin = origin
        self.state = None if state_dir is None else CellState(state_dir, cell_name)
        self.revision = 0
        self.errors = errors
        self.builder = CellBuilder()
        self._waiting: list[Built] = []  # finished builds, in order, to swap in

    def restored(self, scenario: Scenario) -> Scenario:
        """The saved state in force of this cell when there is one for the same origin (the
        edits survive a restart, ``revision`` with them), else ``scenario``."""
        saved = None if self.state is None else self.state.load(self.origin)
        if saved is None:
            return scenario
        try:
            sc = parse_scenario(saved[0], str(self.state.path if self.state else ""))
            check_against_robot(sc)
        except SaraError as e:
            log.error("saved cell state refused (%s): starting from the scenario", e)
            return scenario
        log.warning("restored the cell's edits (revision %d) from %s", saved[1],
                    self.state.path if self.state else "")  # fmt: skip
        self.revision = saved[1]
        return sc

    def persist(self, scenario: Scenario) -> str:
        """Save the state in force; '' or why it could not be saved."""
        if self.state is None:
            return ""
        try:
            self.state.save(self.origin, scenario.model_dump(mode="json"), self.revision)
        except OSError as e:
            self.errors("saving the cell state failed", repr(e))
            return f"applied, but NOT saved to {self.state.path}: {e}"
        return ""

    def drain(self, io: CellBus) -> None:
        """Requested edits off the bus into the builder (refused at once when it is full),
        finished builds into the queue of those to swap in."""
        for d in io.params.drain().messages:
            if isinstance(d.msg, ParamsMsg) and not self.builder.submit(
                d.msg.request_id, d.msg.scenario, d.msg.confirm, d.msg.user
            ):
                io.ack(d.msg.request_id, False, f"busy: {MAX_PENDING_EDITS} edits pending")
        self._waiting.extend(self.builder.done())  # built off the loop: swapped in by the loop

    def take(self, swap: Callable[[Built], bool]) -> None:
        """Hand the finished builds to ``swap`` in order; one that must wait (``swap`` returns
        False) keeps its place and the ones behind it."""
        while self._waiting and swap(self._waiting[0]):
            self._waiting.pop(0)

    def close(self) -> None:
        self.builder.close()
