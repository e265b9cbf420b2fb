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
EDITS_PER_CYCLE = 1
"""Scenario edits the loop decodes in one cycle, at most: an edit may be megabytes of JSON
(tens of ms to decode), and a flood decoded all at once held every one of them in memory
together (the others wait in the request queue, bounded and counted there)."""


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


def unconfirmed_loosening(current: Scenario, b: Built) -> tuple[str | None, list[str]]:
    """Why ``b`` may not run after ``current``: it loosens what the verdict assumes and its
    sender did not confirm that (:mod:`sara_app.ops.loosening`; the API and the dashboard
    confirm and audit, any other editor on the bus must say so too), or None when it may; and
    the loosenings its sender confirmed (each in words). A confirmed loosening is logged with
    who confirmed it."""
    if b.scenario is None:
        return None, []
    try:
        found = check_loosening(current, b.scenario, confirm=b.confirm,
                                how_to_confirm="send it with confirm: true")  # fmt: skip
    except LooseningRefusedError as e:
        return str(e), []
    if found:
        log.warning("edit %s by %r loosens what the verdict assumes, confirmed: %s",
                    b.request_id, b.user or "(no user given)", "; ".join(found))  # fmt: skip
    return None, found


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


def task_pass(old: Cell, new: Cell, pass_index: int) -> tuple[int, bool]:
    """The pass of ``new``'s task the robot goes on in after an edit, and whether it goes on
    in the pass it runs (no re-plan): the same pass while the waypoints stay (a new blend
    distance or number of cycles keeps the task's progress; an edit restarted the task at its
    first pass: 9 passes of a task of 6, hostile-user probe 2026-11-30) and the new task has
    that pass; else the first."""
    same_route = new.scenario.task.waypoints_rad == old.scenario.task.waypoints_rad
    if same_route and 0 <= pass_index < len(new.passes):
        return pass_index, True
    return 0, False


def carry_over(old: Cell, new: Cell, pass_index: int = 0, goes_on: bool = False) -> str | None:
    """Prepare ``new`` to run from now on with the robot's follower and the failsafe it holds
    carried over from ``old`` (verified under the old parameters: the new parameters and safety
    mode take effect from the next verified step), in pass ``pass_index`` of its task
    (:func:`task_pass`; ``goes_on``: the pass the robot runs, else re-planned onto it); None,
    or why ``new`` cannot run now. The task's blend distance applies from the next re-plan
    (a changed route now, else the next pass): the pass under way keeps its corners.

    Another robot model, base pose or limits: only at rest, and the new follower starts where
    the robot rests, through the waypoints of its pass still ahead (as a re-anchor does). It
    started at its task's first waypoint, and the controller, following a valid stream of
    commands, jumped there in one control period (2.4 rad after a velocity limit was lowered
    at rest: found 2026-11-30). Refused live, as they would need the controller
    restarted too: another joint count (the commands, the robot's states and their checks are
    the old robot's) and another control period (a controller reaches each set point one
    period after its command's stamp, the period it started with: after ``shield.dt_s`` went
    from 4 to 40 ms live, the reference controller moved at 9.5 times a joint's velocity
    limit, hostile-user probe 2026-11-30)."""
    sc, was = new.scenario, old.scenario
    same_robot = sc.robot == was.robot and sc.limits == was.limits
    if sc.shield.dt_s != was.shield.dt_s:
        return (
            f"shield.dt_s: the control period ({was.shield.dt_s:g} s) changes only when the "
            f"cell and its robot controller restart with {sc.shield.dt_s:g} s (the controller "
            "reaches each set point one period after the command's stamp)"
        )
    if not same_robot and not old.shield.at_rest:
        return "robot, base pose or limits can change only while the robot is at rest"
    n_old, n_new = old.robot.n_dof, new.robot.n_dof
    if n_new != n_old:
        return (
            f"robot {sc.robot.name!r} has {n_new} joints, the cell's robot "
            f"{was.robot.name!r} {n_old}: restart the cell to run another robot"
        )
    if not same_robot:  # from where the robot rests (the old follower's last command), on its pass
        try:
            new.shield.restart_from(old.shield.robot_state.q, new.passes[pass_index])
        except SaraError as e:
            return str(e)
        return None
    try:
        new.shield.adopt(old.shield)
    except SaraError as e:
        return str(e)
    f = new.shield.follower  # may be the old shield's own: restored if the re-plan fails
    blend = f.blend_distance
    f.blend_distance = sc.task.blend_distance_rad
    try:
        if not goes_on:
            f.replan(new.passes[pass_index])
    except SaraError as e:
        f.blend_distance = blend
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
        for d in io.params.drain(EDITS_PER_CYCLE).messages:
            m = d.msg
            if isinstance(m, ParamsMsg) and not self.builder.submit(
                m.request_id, m.scenario, m.confirm, m.user
            ):
                busy = f"busy: {MAX_PENDING_EDITS} edits pending"
                io.answer("edit", m.request_id, m.user, False, busy, m.confirm)
        self._waiting.extend(self.builder.done())  # built off the loop: swapped in by the loop

    def take(self, swap: Callable[[Built], bool]) -> None:
        """Hand the finished builds to ``swap`` in order; one that must wait (``swap`` returns
        False) keeps its place and the ones behind it."""
        while self._waiting and swap(self._waiting[0]):
            self._waiting.pop(0)

    def close(self) -> None:
        self.builder.close()
