"""The cell worker: one process per cell runs the shield at its control rate on what arrives
over Zenoh, and publishes a command and a verdict every cycle, occupancies for display at a lower
rate and a status heartbeat. It never waits for a subscriber (publishers are fire-and-forget).

Inputs: skeletons (``sara/<cell>/human/<id>/skeleton``), an optional measured robot state (from
a real controller; without one the worker simulates a robot that executes its commands exactly)
and scenario updates (``sara/<cell>/params``, answered on ``params/ack``). A bad message is
dropped and counted; for the shield a dropped skeleton is a missing one (its age grows until the
robot falls back to its failsafe).

This module is the cycle and its loop; its parts, one concept each: the bus
(:mod:`~sara_app.runtime.bus_io`), the people (:mod:`~sara_app.runtime.people`), the measured
robot (:mod:`~sara_app.runtime.robot_link`), live edits (:mod:`~sara_app.runtime.edits`), the
cycle's verdict and command (:mod:`~sara_app.runtime.messages`) and the display
(:mod:`~sara_app.runtime.display`).
"""

from __future__ import annotations

import gc
import logging
import math
import sys
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np

from sara_app.bus import keys
from sara_app.bus.compact import CommandArrays
from sara_app.bus.messages import OccupancyMsg, ReplanMsg, ScenarioStateMsg, StatusMsg
from sara_app.bus.ownership import claim_cell
from sara_app.bus.process import SummarisedWarning, process_main
from sara_app.bus.session import Bus
from sara_app.bus.starting import Starting, last_status_seq
from sara_app.cell.build import Cell, build_cell
from sara_app.cell.intake import Track
from sara_app.errors import SaraError
from sara_app.robot.deviation_kernels import max_abs_diff
from sara_app.robot.trajectory import JointState
from sara_app.runtime import display
from sara_app.runtime.bus_io import CellBus
from sara_app.runtime.cadence import PhaseLock
from sara_app.runtime.edits import (
    Built,
    LiveEdits,
    build,
    carry_over,
    task_pass,
    unconfirmed_loosening,
)
from sara_app.runtime.ledger import AnswerLedger
from sara_app.runtime.messages import CycleMessages
from sara_app.runtime.people import People
from sara_app.runtime.presence import Presence
from sara_app.runtime.robot_link import MeasuredRobot, outside_limits
from sara_app.safety.shield import CycleResult, Shield
from sara_app.scenario import Scenario

log = logging.getLogger("sara_app.worker")
BUILDING = "building the cell: loading the robot model and compiling the safety kernels"
_MIN_SLEEP_S = 20e-6  # the least the loop sleeps per cycle, even when late (s)
REPLANS_PER_CYCLE = 2
"""Re-plan requests taken per cycle at most (the rest wait in the subscription's queue): a flood
of them took the worker's every cycle (hostile-user probe, 2026-11-30)."""
REPLAN_MAX_AGE_S = 3.0
"""A re-plan request older than this is refused (a replayed one; the API waits 3 s)."""


class _Throttle:
    """Rate-limited logging: the first occurrence of each kind with its traceback, then the
    1st, 2nd, 4th, 8th ... as one line with the count."""

    def __init__(self) -> None:
        self.counts: dict[str, int] = {}

    def __call__(self, kind: str, message: str, exc: BaseException | None = None) -> None:
        n = self.counts[kind] = self.counts.get(kind, 0) + 1
        if n == 1:
            log.error("%s: %s", kind, message, exc_info=exc)
        elif n & (n - 1) == 0:
            log.error("%s (#%d): %s", kind, n, message)


class CellWorker:
    """Runs one cell. ``step(now)`` is one cycle (used by ``run`` and by tests)."""

    def __init__(
        self,
        cell_name: str,
        scenario: Scenario,
        bus: Bus,
        *,
        loop_task: bool = True,
        display_hz: float = 15.0,
        status_hz: float = 1.0,
        state_dir: str | Path | None = None,
        origin: str | None = None,
        audit: str | Path | None = None,
    ) -> None:
        self.name = keys.check_name("cell", cell_name)
        self.bus = bus
        self.token = claim_cell(bus, self.name)  # one worker per cell, or none
        self.errors = _Throttle()
        self._reanchored_log = SummarisedWarning(log, "robot at rest elsewhere")
        self.edits = LiveEdits(self.name, origin or scenario.name, state_dir, self.errors)
        scenario = self.edits.restored(scenario)
        self.loop_task = loop_task
        self.display_period = 1.0 / display_hz
        self.status_period = 1.0 / status_hz
        status = bus.publisher(keys.status_key(self.name))
        status.continue_after(last_status_seq(self.name))  # after the entry point's
        with Starting(status, self.name, scenario.name, BUILDING):
            self.cell = build_cell(scenario)
        self.io = CellBus(bus, self.name, status, lambda: self.cell.robot.limits.v_max)
        if audit is not None:
            self.io.ledger = AnswerLedger(audit, self.name, lambda: self.cell.checksum)
        self.people = People(self.cell, self.io, self.errors)
        self.robot_in = MeasuredRobot()
        self.pass_index = 0
        self.cycle_us: deque[float] = deque(maxlen=2000)
        self.loop_us: deque[float] = deque(maxlen=2000)
        """The whole step's time per cycle (inputs, the shield, the messages sent), us."""
        self.overruns = 0
        self.t_cmd = -math.inf
        """The last cycle's time: its command's stamp (:meth:`step`)."""
        self.started = time.time()
        self._next_display = 0.0
        self._next_status = 0.0
        self.last: CycleResult | None = None
        self.stop_event = threading.Event()
        self.messages = CycleMessages(self.name, self.cell.robot.n_dof)
        self.phase = PhaseLock(self.shield.settings.dt_s)

    @property
    def min_gap_s(self) -> float:
        """The least time between two commands' stamps (:meth:`step`)."""
        dt = self.shield.settings.dt_s
        return (
            dt * (1.0 - self.phase.max_slew) if self.cell.scenario.inputs.cycle_phase_lock else dt
        )

    @property
    def shield(self) -> Shield:
        return self.cell.shield

    @property
    def presence(self) -> Presence:
        return self.people.presence

    @property
    def tracks(self) -> dict[str, Track]:
        return self.presence.tracks

    # -- inputs --------------------------------------------------------------------------------

    def _ingest(self, now: float) -> None:
        self.people.drain(now)
        if self.cell.scenario.inputs.cycle_phase_lock:
            self.phase.observe(now, self.people.fresh_stamps)
        sc = self.cell.scenario
        self.robot_in.rest_speed = sc.inputs.robot_rest_speed_rad_s  # the scenario in force
        self.robot_in.drain(self.io.robot_state, now, sc.shield.tracking_tol_rad)
        self.robot_in.hear_controller(self.io.controller_status, now)
        self.people.drain_retirements(now)
        self._drain_replans(now)
        self.edits.drain(self.io)
        self.edits.take(self._take)

    def _drain_replans(self, now: float) -> None:
        """An operator's word that the robot stands where its controller says
        (``robot/replan``): the plan starts from the measured state, or the request is refused
        with the reason; answered either way, logged with who asked."""
        for d in self.io.replan.drain(REPLANS_PER_CYCLE).messages:
            m = d.msg
            if not isinstance(m, ReplanMsg):
                continue
            why = self._replan_refusal(m, now)
            if why is None and self.robot_in.state is not None:
                try:
                    self.shield.restart_from(self.robot_in.state.q)
                except SaraError as e:  # answered, never left unanswered by a raise
                    why = f"no plan from there: {e}"
            if why is None:
                self.robot_in.forget_commands()
                log.warning("the plan starts from the measured robot state, confirmed by %r: %r",
                            m.user, m.reason)  # fmt: skip
            else:
                self.errors("re-plan refused", why)
            self.io.answer("replan", m.request_id, m.user, why is None, why or "")

    def _replan_refusal(self, m: ReplanMsg, now: float) -> str | None:
        n, sc = self.cell.robot.n_dof, self.cell.scenario
        age = now - m.stamp_s
        if not age <= REPLAN_MAX_AGE_S:
            return f"the request is {age:.1f} s old (at most {REPLAN_MAX_AGE_S} s)"
        if len(m.q) != n:
            return f"{len(m.q)} joint positions confirmed; the robot has {n}"
        if not self.shield.at_rest:
            return (
                "the worker's plan is not at rest (it moves, or still brakes): a re-plan is for "
                "a robot stopped away from the plan, once the plan has stopped too"
            )
        tol, lim = sc.shield.tracking_tol_rad, self.cell.robot.limits
        why = self.robot_in.replan_refusal(
            np.asarray(m.q, dtype=float), now, sc.inputs.robot_state_timeout_s, tol,
            lim.q_min, lim.q_max,
        )  # fmt: skip
        if why is None and self.robot_in.state is not None:
            off = max_abs_diff(self.robot_in.state.q, self.shield.robot_state.q)
            if off <= tol:
                return f"the robot stands where the plan is ({off:.4f} rad): nothing to re-plan"
        return why

    def _take(self, b: Built) -> bool:
        """Swap a finished build in and answer it; False while it must wait for the robot to
        come to rest (leaving a mode that holds no verified failsafe: it is halted meanwhile).
        An edit that loosens what the verdict assumes without its sender's confirmation is
        refused first (:func:`~sara_app.runtime.edits.unconfirmed_loosening`)."""
        refused, loosens = unconfirmed_loosening(self.cell.scenario, b)
        if refused is not None:
            self.io.answer("edit", b.request_id, b.user, False, refused, b.confirm)
            return True
        if b.cell is not None and self._needs_rest(b.cell) and not self.shield.at_rest:
            self.shield.halt_reason = f"stopping for the switch to {b.cell.shield.safety_mode}"
            return False
        ok, reason = (False, b.error) if b.cell is None else self._swap(b.cell)
        self.shield.halt_reason = None  # refused or done: the mode runs on
        if ok:  # on disk, then announced, then acknowledged: an ack means all three
            reason = self.edits.persist(self.cell.scenario)
            self.io.scenario.put(self.scenario_msg(time.time()))
        said = reason  # the record says what the sender confirmed
        if ok and loosens:
            said = f"confirmed loosening: {'; '.join(loosens)}" + (f"; {reason}" if reason else "")
        self.io.answer("edit", b.request_id, b.user, ok, reason, b.confirm, recorded=said)
        return True

    def _needs_rest(self, new: Cell) -> bool:
        """Whether running ``new`` needs the robot at rest first (leaving a mode that holds no
        verified failsafe for another mode)."""
        old = self.shield
        return not old.holds_failsafe and new.shield.safety_mode != old.safety_mode

    def apply(self, data: dict) -> tuple[bool, str]:
        """Validate a scenario and apply it now, in the caller's thread (the loop builds edits
        off the loop instead, see :mod:`~sara_app.runtime.edits`); never half-applied. Returns
        (accepted, why). In-process: the caller owns the worker, so no loosening is compared
        (the bus's edits are, in :meth:`_take`)."""
        built = build("apply", data)
        return (False, built.error) if built.cell is None else self._swap(built.cell)

    def _swap(self, new: Cell) -> tuple[bool, str]:
        """Run ``new`` from now on, with the robot's follower and failsafe carried over and
        every person kept (:meth:`People.adopt <sara_app.runtime.people.People.adopt>`)."""
        k, goes_on = task_pass(self.cell, new, self.pass_index)
        why = carry_over(self.cell, new, k, goes_on)
        if why is not None:
            return False, why
        self.pass_index = k
        self.cell = new
        self.people.adopt(new)
        self.edits.revision += 1
        gc.freeze()  # the new cell joins the frozen heap (see bus.process.freeze_heap)
        return True, ""

    # -- the cycle -----------------------------------------------------------------------------

    def step(self, now: float) -> CycleResult:
        """One cycle: inputs, the shield, one command and one verdict. Whatever raises on the
        way makes the cycle a fault on the held failsafe, never an exception out of here.

        The inputs are judged at ``now``; the cycle's time is ``t_cmd = max(now, the previous
        cycle's + min_gap_s)``: it is verified at that time (the people's sets grown for the
        extra age), and its verdict and command are stamped then (set point at ``t_cmd +
        dt``). Commands are thus never less than ``min_gap_s`` (one period; 2 % less with the
        phase lock, as the contract allows) apart, however close together the cycles ran: a
        worker catching up after a late cycle (its loop runs the next one at once) stamped
        commands 1.1 ms apart at a 4 ms period, and the robot covered a whole verified step in
        that gap, up to 15.8x ``v_max`` (robot channel probe, 2026-12-01). :meth:`run` keeps
        ``t_cmd`` within a period of the clock and brings it back to it."""
        t0_ns = time.perf_counter_ns()
        self.t_cmd = t_cmd = max(now, self.t_cmd + self.min_gap_s)
        problems: list[str] = []
        try:
            self._ingest(now)
        except Exception as e:  # noqa: BLE001 - an input failure is a fault, not a crash
            self.errors("input handling failed", repr(e), e)
            problems.append(f"input handling failed: {e!r}"[:200])
        sc = self.cell.scenario
        try:
            robot = self._reanchor(now) + self.robot_in.faults(
                now, sc.inputs.robot_state_timeout_s, sc.shield.tracking_tol_rad
            )
            faults = self.presence.faults(now) + self.presence.conformance() + robot + problems
            # the tracking check is the measured robot's (at the measurement's time)
            res = self.shield.cycle(t_cmd, self.presence.humans(), None, input_faults=faults)
        except Exception as e:  # noqa: BLE001 - last line of defence: brake, report, go on
            self.errors("worker cycle failed", repr(e), e)
            res = self._fault_cycle(t_cmd, f"cycle failed: {e!r}"[:200])
        self.last = res
        self.cycle_us.append(res.cycle_time_us)
        try:
            self._advance_task()
        except Exception as e:  # noqa: BLE001
            self.errors("task advance failed", repr(e), e)
        self._publish(t_cmd, res)
        self.loop_us.append((time.perf_counter_ns() - t0_ns) / 1e3)
        return res

    def _reanchor(self, now: float) -> list[str]:
        """A robot at rest where the follower is not (a restarted worker; a controller that
        braked on its own while the worker hung): when the follower rests too, start it from
        the measured position (towards its path's end), so commands continue from there.
        Returns the cycle's fault when the robot rests outside its joint limits: no plan
        starts there (restarting raised in every cycle, a traceback each time)."""
        tol = self.cell.scenario.shield.tracking_tol_rad
        q_meas = None if self.robot_in.state is None else self.robot_in.state.q
        if q_meas is None or not self.shield.at_rest:
            return []
        timeout = self.cell.scenario.inputs.robot_state_timeout_s
        if not self.robot_in.at_rest_elsewhere(self.shield.robot_state.q, now, timeout, tol):
            return []
        lim = self.cell.robot.limits
        why = outside_limits(q_meas, lim.q_min, lim.q_max)
        if why is not None:
            return [f"robot at rest outside its joint limits, not planned from there: {why}"]
        self.shield.restart_from(q_meas)
        self.robot_in.forget_commands()
        self._reanchored_log("follower re-anchored at the measured state")
        return []

    def _fault_cycle(self, now: float, why: str) -> CycleResult:
        """A cycle that failed outside the shield's own fault handling: brake on the held
        failsafe (if even that fails, hold the last commanded state)."""
        try:
            command = self.shield.brake_step()
        except Exception as e:  # noqa: BLE001
            self.errors("braking failed", repr(e), e)
            command = self.shield.robot_state
        return CycleResult(
            t_s=now,
            mode="fault",
            verified=False,
            command=command,
            faults=[why],
            safety_mode=self.shield.safety_mode,
            intervened=True,
        )

    def _advance_task(self) -> None:
        f = self.shield.follower
        if not self.shield.task_done:
            return
        nxt = self.cell.next_pass(self.pass_index, self.loop_task)
        if nxt is None:
            return
        self.pass_index = nxt
        try:
            f.replan(self.cell.passes[nxt])
        except SaraError as e:
            self.errors("task replan failed", str(e))

    def _publish(self, now: float, res: CycleResult) -> None:
        """One verdict, then one command (never an ``intended`` command without its verdict:
        when the verdict cannot be sent, the command goes out as ``fault``)."""
        dt = self.shield.settings.dt_s
        seqs = (self.io.verdict.next_seq(), self.io.command.next_seq())
        command: CommandArrays | None
        try:
            self.messages.observe(now, res, self.shield.holds_failsafe)
            verdict, command = self.messages.verdict_and_command(
                now, dt, res, self.io.dropped(), seqs, self.presence, self.shield.blocking(res)
            )
        except Exception as e:  # noqa: BLE001 - a message that cannot be built: a fault cycle
            self.errors("building the cycle's messages failed", repr(e), e)
            why = f"messages failed: {e!r}"[:200]
            verdict, command = self.messages.fault(now, dt, res, why, self.io.dropped(), seqs)
        if not self.io.verdict.put(verdict) and command is not None and command.mode == "intended":
            command = command._replace(mode="fault")
        if command is not None:  # None: nothing commanded yet, and nothing to hold now
            self.io.command.put(command)
            self.messages.last = JointState(command.q, command.q_dot, command.q_ddot)
            self.robot_in.sent(command.stamp_s + dt, command.q, command.stop_arrays())
        try:
            if now >= self._next_display:
                self._next_display = now + self.display_period
                self.io.occupancy.put(self.occupancy_msg(now, res))
        except Exception as e:  # noqa: BLE001 - display only: counted, logged, never a fault
            self.errors("occupancy display failed", repr(e), e)
        if now >= self._next_status:
            self._next_status = now + self.status_period
            try:
                self.io.status.put(self.status_msg(now, "running"))
                self.io.scenario.put(self.scenario_msg(now))
            except Exception as e:  # noqa: BLE001 - the cycle's verdict and command went out;
                # a heartbeat that cannot be built is logged and counted, and the cell shows as
                # offline where its statuses stop (the registry's rule), never a crashed loop
                self.errors("status heartbeat failed", repr(e), e)

    def occupancy_msg(self, now: float, res: CycleResult) -> OccupancyMsg:
        return display.occupancy_msg(
            self.cell, self.tracks.values(), res, now, self.io.occupancy.next_seq, self.errors
        )

    def scenario_msg(self, now: float) -> ScenarioStateMsg:
        seq = self.io.scenario.next_seq()
        return display.scenario_msg(self.name, self.cell, self.edits.revision, now, seq)

    def status_msg(self, now: float, state: str) -> StatusMsg:
        return display.status_msg(
            self.name, self.cell, state, now, self.io.status.next_seq(),
            uptime_s=now - self.started, humans=self.tracks, cycle_us=self.cycle_us,
            loop_us=self.loop_us, overruns=self.overruns,
            robot_q=None if self.robot_in.state is None else self.robot_in.state.q.tolist(),
            phase=self.phase if self.cell.scenario.inputs.cycle_phase_lock else None,
        )  # fmt: skip

    def run(self, duration_s: float | None = None) -> None:
        """Cycle at the scenario's rate until ``stop_event`` is set (or ``duration_s``)."""
        t_end = None if duration_s is None else time.monotonic() + duration_s
        next_t = time.monotonic()
        while not self.stop_event.is_set():
            mono = time.monotonic()
            if t_end is not None and mono >= t_end:
                break
            lead_s = self.t_cmd - time.time()
            if lead_s > 0.0:  # the next cycle's time would lead the clock by over a period
                time.sleep(lead_s)
            self.step(time.time())  # never raises (a failed cycle is a fault cycle)
            dt = self.shield.settings.dt_s
            next_t += dt
            if self.cell.scenario.inputs.cycle_phase_lock:
                next_t += self.phase.slew_s()
            # a cycle time ahead of the clock (after a catch-up): periods up to 2 % longer
            # until the clock has caught up (the people's sets are grown by the lead meanwhile)
            next_t += min(max(self.t_cmd - time.time(), 0.0), self.phase.max_slew * dt)
            delay = next_t - time.monotonic()
            # never a busy loop: under SCHED_FIFO an overrunning worker would otherwise keep its
            # CPU from every normally scheduled thread (zenoh I/O included)
            time.sleep(max(delay, _MIN_SLEEP_S))
            if delay < -self.shield.settings.dt_s:
                self.overruns += 1
                next_t = time.monotonic()
        try:
            self.io.status.put(self.status_msg(time.time(), "stopping"))
        except Exception as e:  # noqa: BLE001 - the cell is given up below either way
            self.errors("status heartbeat failed", repr(e), e)
        self.edits.close()
        if self.io.ledger is not None:
            self.io.ledger.close()
        self.release()

    def release(self) -> None:
        """Give the cell up (another worker may claim it)."""
        if self.token is not None:
            try:
                self.token.undeclare()
            except Exception:  # noqa: BLE001 - a closed session has released it already
                pass
            self.token = None


def main(argv: list[str] | None = None) -> int:
    return process_main("worker", "run one cell worker", CellWorker, argv, state=True)


if __name__ == "__main__":
    sys.exit(main())
