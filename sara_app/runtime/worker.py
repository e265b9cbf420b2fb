"""The cell worker: one process per cell runs the shield at its control rate on what arrives
over Zenoh, and publishes a command and a verdict every cycle, occupancies for display at a lower
rate and a status heartbeat. It never waits for a subscriber (publishers are fire-and-forget).

Inputs: skeletons (``sara/<cell>/human/<id>/skeleton``), an optional measured robot state (from
a real controller; without one the worker simulates a robot that executes its commands exactly)
and scenario updates (``sara/<cell>/params``, answered on ``params/ack``). A bad message is
dropped and counted; for the shield a dropped skeleton is a missing one (its age grows until the
robot falls back to its failsafe).
"""

from __future__ import annotations

import gc
import logging
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from sara_app.bus import keys
from sara_app.bus.codec import Decoder
from sara_app.bus.messages import (
    CapsulesMsg,
    HumanOccupancyMsg,
    OccupancyMsg,
    ParamsAckMsg,
    ParamsMsg,
    RetireMsg,
    RobotOccupancyMsg,
    RobotStateMsg,
    ScenarioStateMsg,
    SkeletonMsg,
    StatusMsg,
    TrackerFrameMsg,
)
from sara_app.bus.ownership import claim_cell
from sara_app.bus.process import process_main
from sara_app.bus.session import Bus
from sara_app.bus.starting import Starting, last_status_seq
from sara_app.cell.build import Cell, build_cell
from sara_app.cell.intake import Track, rewiden, track_for
from sara_app.errors import SaraError
from sara_app.human.reach import MODELS, part_capsules
from sara_app.human.widening import per_capsule
from sara_app.robot.trajectory import JointState
from sara_app.runtime.cell_state import CellState
from sara_app.runtime.display import (
    EFFECTIVE,
    effective_set,
    jssa_state,
    part_labels,
    pfl_contacts,
    pfl_links,
)
from sara_app.runtime.edits import MAX_PENDING_EDITS, Built, CellBuilder, build
from sara_app.runtime.ingest import ingest_skeleton
from sara_app.runtime.messages import CycleMessages
from sara_app.runtime.presence import Presence
from sara_app.runtime.robot_link import MeasuredRobot
from sara_app.safety.jssa_mode import JssaMode
from sara_app.safety.pfl_shield import PflShield
from sara_app.safety.settings import FUTURE_TOLERANCE_S
from sara_app.safety.shield import CycleResult, Shield
from sara_app.safety.thresholds import link_shapes
from sara_app.scenario import Scenario, check_against_robot, parse_scenario

log = logging.getLogger("sara_app.worker")
BUILDING = "building the cell: loading the robot model and compiling the safety kernels"
_MIN_SLEEP_S = 20e-6  # the least the loop sleeps per cycle, even when late (s)
SKELETON_QUEUE = 4096
"""Skeleton samples queued between two drains (all people); each drain decodes only the newest
of each key, so a flood on one key cannot crowd out another person's newest message."""


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
    ) -> None:
        self.name = keys.check_name("cell", cell_name)
        self.bus = bus
        self.token = claim_cell(bus, self.name)  # one worker per cell, or none
        self.origin = origin or scenario.name
        self.state = None if state_dir is None else CellState(state_dir, self.name)
        scenario, revision = self._restored(scenario)
        self.loop_task = loop_task
        self.display_period = 1.0 / display_hz
        self.status_period = 1.0 / status_hz
        self.pub_status = bus.publisher(keys.status_key(self.name))
        self.pub_status.continue_after(last_status_seq(self.name))  # after the entry point's
        with Starting(self.pub_status, self.name, scenario.name, BUILDING):
            self.cell = build_cell(scenario)
        inp = scenario.inputs
        self.presence = Presence(
            tuple(inp.trackers), inp.tracker_timeout_s, inp.max_people, self._new_track
        )
        self.robot_in = MeasuredRobot()
        self.pass_index = 0
        self.cycle_us: deque[float] = deque(maxlen=2000)
        self.started = time.time()
        self._next_display = 0.0
        self._next_status = 0.0
        self.last: CycleResult | None = None
        self.stop_event = threading.Event()
        self.errors = _Throttle()
        # one set of drop counters for every input
        self.decoder = Decoder(max_future_s=FUTURE_TOLERANCE_S)
        self.sub_skel = bus.subscribe(
            keys.skeleton_keys(self.name), self.decoder, capacity=SKELETON_QUEUE
        )
        self.sub_frames = bus.subscribe(keys.tracker_frame_keys(self.name), self.decoder)
        self.sub_state = bus.subscribe(keys.robot_state_key(self.name), self.decoder)
        self.sub_params = bus.subscribe(keys.params_key(self.name), self.decoder, fifo=True)
        self.sub_retire = bus.subscribe(keys.retire_key(self.name), self.decoder, fifo=True)
        self.pub_cmd = bus.publisher(keys.robot_command_key(self.name))
        self.pub_verdict = bus.publisher(keys.verdict_key(self.name))
        self.pub_occ = bus.publisher(keys.occupancy_key(self.name), express=False)
        self.pub_ack = bus.publisher(keys.params_ack_key(self.name))
        self.pub_scenario = bus.publisher(keys.scenario_key(self.name))
        self.scenario_revision = revision
        self.messages = CycleMessages(self.name, self.cell.robot.n_dof)
        self.builder = CellBuilder()
        self._waiting: list[Built] = []  # finished builds, in order, to swap in

    def _restored(self, scenario: Scenario) -> tuple[Scenario, int]:
        """The saved state in force of this cell when there is one for the same origin (the
        edits survive a restart), else ``scenario``."""
        saved = None if self.state is None else self.state.load(self.origin)
        if saved is None:
            return scenario, 0
        try:
            sc = parse_scenario(saved[0], str(self.state.path if self.state else ""))
            check_against_robot(sc)
        except SaraError as e:
            log.error("saved cell state refused (%s): starting from the scenario", e)
            return scenario, 0
        log.warning("restored the cell's edits (revision %d) from %s", saved[1],
                    self.state.path if self.state else "")  # fmt: skip
        return sc, saved[1]

    def _persist(self) -> str:
        """Save the state in force; '' or why it could not be saved."""
        if self.state is None:
            return ""
        try:
            sc = self.cell.scenario.model_dump(mode="json")
            self.state.save(self.origin, sc, self.scenario_revision)
        except OSError as e:
            self.errors("saving the cell state failed", repr(e))
            return f"applied, but NOT saved to {self.state.path}: {e}"
        return ""

    @property
    def shield(self) -> Shield:
        return self.cell.shield

    @property
    def tracks(self) -> dict[str, Track]:
        return self.presence.tracks

    def _new_track(self, human_id: str) -> Track:
        return track_for(self.cell, human_id)

    # -- inputs --------------------------------------------------------------------------------

    def _drop(self, reason: str) -> None:
        self.decoder.count(reason)

    def _ingest_skeleton(self, human_id: str, msg: SkeletonMsg) -> None:
        track = self.presence.known(human_id, msg.stamp_s)
        if track is None:
            self._drop("too_many_people")
            return
        reason = ingest_skeleton(self.cell, track, msg)
        if reason is not None:
            self._drop(reason)

    def _ingest(self, now: float) -> None:
        skel = self.sub_skel.drain_latest()
        for d in skel.messages:
            if isinstance(d.msg, SkeletonMsg) and d.key.human_id:
                try:
                    self._ingest_skeleton(d.key.human_id, d.msg)
                except Exception as e:  # noqa: BLE001 - this message only: the person is unseen
                    self.errors("skeleton ingest failed", repr(e), e)
                    self._drop("internal")
                    self.presence.refused(d.key.human_id, now)
        for key in skel.refused_keys:
            hid = _id_in(key, "skeleton")
            if hid is not None:  # a refused message on a person's key: that person is unseen
                self.presence.refused(hid, now)
        frames = self.sub_frames.drain_latest()
        for d in frames.messages:
            if isinstance(d.msg, TrackerFrameMsg) and d.key.human_id:
                reason = self.presence.frame(d.key.human_id, d.msg.stamp_s, d.msg.people)
                if reason is not None:
                    self._drop(reason)
        self._ingest_robot(now)
        for d in self.sub_retire.drain().messages:
            if isinstance(d.msg, RetireMsg):
                found = self.presence.retire(d.msg.human_id)
                if found:
                    log.warning("human %r retired by %r: %s", d.msg.human_id, d.msg.user,
                                d.msg.reason)  # fmt: skip
                else:  # rate-limited: anyone may send these
                    self.errors("retire of an unknown person", repr(d.msg.human_id))
                reason = "" if found else f"human {d.msg.human_id!r} is not known"
                self._ack(d.msg.request_id, found, reason)
        for d in self.sub_params.drain().messages:
            if isinstance(d.msg, ParamsMsg) and not self.builder.submit(
                d.msg.request_id, d.msg.scenario
            ):
                self._ack(d.msg.request_id, False, f"busy: {MAX_PENDING_EDITS} edits pending")
        for b in self.builder.done():  # built off the loop: swapped in here
            self._waiting.append(b)
        while self._waiting and self._take(self._waiting[0]):
            self._waiting.pop(0)

    def _take(self, b: Built) -> bool:
        """Swap a finished build in and answer it; False while it must wait for the robot to
        come to rest (leaving JSSA, which holds no verified failsafe: it is halted meanwhile)."""
        if b.cell is not None and self._needs_rest(b.cell) and not self.shield.at_rest:
            if isinstance(self.shield, JssaMode):
                self.shield.halt_reason = f"stopping for the switch to {b.cell.shield.safety_mode}"
                return False
        ok, reason = (False, b.error) if b.cell is None else self._swap(b.cell)
        if isinstance(self.shield, JssaMode):
            self.shield.halt_reason = None  # refused or done: JSSA runs on
        if ok:  # on disk, then announced, then acknowledged: an ack means all three
            reason = self._persist()
            self.pub_scenario.put(self.scenario_msg(time.time()))
        self._ack(b.request_id, ok, reason)
        return True

    def _needs_rest(self, new: Cell) -> bool:
        """Whether running ``new`` needs the robot at rest first (from JSSA to another mode)."""
        return self.shield.safety_mode == "jssa" and new.shield.safety_mode != "jssa"

    def _ingest_robot(self, now: float) -> None:
        got = self.sub_state.drain_latest()
        n_dof = self.cell.robot.n_dof
        for d in got.messages:
            if not isinstance(d.msg, RobotStateMsg):
                continue
            if len(d.msg.q) != n_dof:
                self._drop("wrong_dof")
                self.robot_in.problem = f"{len(d.msg.q)} joints received, robot has {n_dof}"
                continue
            self.robot_in.state = JointState(
                q=np.asarray(d.msg.q), v=np.asarray(d.msg.q_dot), a=np.zeros(n_dof)
            )
            self.robot_in.stamp_s = d.msg.stamp_s
            self.robot_in.problem = None
        if got.refused_keys and not got.messages:
            self.robot_in.problem = "the last message was refused (see dropped)"

    def _ack(self, request_id: str, ok: bool, reason: str) -> None:
        self.pub_ack.put(
            ParamsAckMsg(
                seq=self.pub_ack.next_seq(),
                stamp_s=time.time(),
                request_id=request_id,
                accepted=ok,
                reason=reason,
            )
        )

    def apply(self, data: dict) -> tuple[bool, str]:
        """Validate a scenario and apply it now, in the caller's thread (the loop builds edits
        off the loop instead, see ``worker_edits``); never half-applied. Returns (accepted,
        why)."""
        built = build("apply", data)
        return (False, built.error) if built.cell is None else self._swap(built.cell)

    def _swap(self, new: Cell) -> tuple[bool, str]:
        """Run ``new`` from now on, with the robot's follower and failsafe carried over.

        Every person stays known with their measurement and faults (``Presence``); their
        velocity error bounds are re-derived under the new parameters from the next skeleton
        on (until then the acceleration model is unusable for them: infinite bound)."""
        sc = new.scenario
        old = self.cell
        same_robot = sc.robot == old.scenario.robot and sc.limits == old.scenario.limits
        if not same_robot and not old.shield.at_rest:
            return False, "robot, base pose or limits can change only while the robot is at rest"
        if same_robot:
            # keep the follower and the failsafe it holds (verified under the old parameters:
            # the new parameters and safety mode take effect from the next verified step)
            try:
                new.shield.adopt(old.shield)
                if sc.task != old.scenario.task:
                    new.shield.follower.replan(new.passes[0])
            except SaraError as e:
                return False, str(e)
        self.cell = new
        self.pass_index = 0
        inp = sc.inputs
        self.presence.configure(
            inp.trackers, inp.tracker_timeout_s, inp.max_people, self._new_track
        )
        p, gate = new.params, inp.gate.intake()
        for t in self.presence.tracks.values():
            t.intake.retune(p.delta_y_m, p.v_max_mps, p.a_max_mps2, gate)
            t.state.dv = np.full(len(p.v_max_mps), np.inf)
            rewiden(new, t)  # the same message under the new delta_y
        self.scenario_revision += 1
        gc.freeze()  # the new cell joins the frozen heap (see bus.process.freeze_heap)
        return True, ""

    # -- the cycle -----------------------------------------------------------------------------

    def step(self, now: float) -> CycleResult:
        """One cycle: inputs, the shield, one command and one verdict. Whatever raises on the
        way makes the cycle a fault on the held failsafe, never an exception out of here."""
        problems: list[str] = []
        try:
            self._ingest(now)
        except Exception as e:  # noqa: BLE001 - an input failure is a fault, not a crash
            self.errors("input handling failed", repr(e), e)
            problems.append(f"input handling failed: {e!r}"[:200])
        sc = self.cell.scenario
        try:
            self._reanchor()
            robot = self.robot_in.faults(
                now, sc.inputs.robot_state_timeout_s, sc.shield.tracking_tol_rad
            )
            faults = self.presence.faults(now) + self.presence.conformance() + robot + problems
            # the tracking check is the measured robot's (at the measurement's time)
            res = self.shield.cycle(now, self.presence.humans(), None, input_faults=faults)
        except Exception as e:  # noqa: BLE001 - last line of defence: brake, report, go on
            self.errors("worker cycle failed", repr(e), e)
            res = self._fault_cycle(now, f"cycle failed: {e!r}"[:200])
        self.last = res
        self.cycle_us.append(res.cycle_time_us)
        try:
            self._advance_task()
        except Exception as e:  # noqa: BLE001
            self.errors("task advance failed", repr(e), e)
        self._publish(now, res)
        return res

    def _reanchor(self) -> None:
        """A robot at rest where the follower is not (a restarted worker; a controller that
        braked on its own while the worker hung): when the follower rests too, start it from
        the measured position (towards its path's end), so commands continue from there."""
        tol = self.cell.scenario.shield.tracking_tol_rad
        q_meas = None if self.robot_in.state is None else self.robot_in.state.q
        if q_meas is None or not self.shield.at_rest:
            return
        if self.robot_in.at_rest_elsewhere(self.shield.robot_state.q, tol):
            self.shield.restart_from(q_meas)
            self.robot_in.commanded.clear()
            log.warning("robot at rest elsewhere: follower re-anchored at the measured state")

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

    def dropped(self) -> dict[str, int]:
        return dict(self.decoder.counts)

    def _publish(self, now: float, res: CycleResult) -> None:
        """One verdict, then one command (never an ``intended`` command without its verdict:
        when the verdict cannot be sent, the command goes out as ``fault``)."""
        dt = self.shield.settings.dt_s
        seqs = (self.pub_verdict.next_seq(), self.pub_cmd.next_seq())
        try:
            self.messages.observe(now, res)
            verdict, command = self.messages.verdict_and_command(
                now, dt, res, self.dropped(), seqs, self.presence
            )
        except Exception as e:  # noqa: BLE001 - a message that cannot be built: a fault cycle
            self.errors("building the cycle's messages failed", repr(e), e)
            why = f"messages failed: {e!r}"[:200]
            verdict, command = self.messages.fault(now, dt, res, why, self.dropped(), seqs)
        if not self.pub_verdict.put(verdict) and command.mode == "intended":
            command = command.model_copy(update={"mode": "fault"})
        self.pub_cmd.put(command)
        q = np.asarray(command.q)
        self.messages.last = JointState(q, np.asarray(command.q_dot), np.asarray(command.q_ddot))
        self.robot_in.sent(command.stamp_s + dt, command)
        try:
            if now >= self._next_display:
                self._next_display = now + self.display_period
                self.pub_occ.put(self.occupancy_msg(now, res))
        except Exception as e:  # noqa: BLE001 - display only: counted, logged, never a fault
            self.errors("occupancy display failed", repr(e), e)
        if now >= self._next_status:
            self._next_status = now + self.status_period
            self.pub_status.put(self.status_msg(now, "running"))
            self.pub_scenario.put(self.scenario_msg(now))

    def occupancy_msg(self, now: float, res: CycleResult) -> OccupancyMsg:
        """Human sets over the whole shielded trajectory (one interval from the measurement to
        its end) for every enabled model, and the robot's interval capsules."""
        humans = []
        reach = self.shield.reach
        horizon = 0.0 if res.trajectory is None else res.trajectory.duration_s
        for t in self.presence.tracks.values():
            st = t.state
            if st.stamp_s is None:
                continue
            age = max(now - st.stamp_s, 0.0)
            models = {}
            per_part = []  # (ends, radius, part map) of the models that map body parts
            for name in self.shield.verifier.models:
                try:
                    o = reach.model(
                        name,
                        st.y[None],
                        st.v[None],
                        st.dv[None],
                        np.array([age]),
                        np.array([age + horizon]),
                    )
                    part_map = part_capsules(reach, name)
                except SaraError:
                    continue
                radius = o.radius[0, 0]
                if st.widen_m is not None:  # as verified: widened per body part
                    row = st.widen_m[MODELS.index(name)]
                    radius = radius + per_capsule(row, part_map, len(radius))
                if np.all(np.isfinite(radius)):
                    models[name] = CapsulesMsg.from_arrays(o.ends[0, 0], radius)
                    per_part.append((o.ends[0, 0], radius, part_map))
            eff = effective_set(per_part)
            if eff is not None:
                models[EFFECTIVE] = CapsulesMsg.from_arrays(*eff)
            humans.append(
                HumanOccupancyMsg(
                    id=st.id, kind="full", joints_m=st.y.ravel().tolist(), models=models
                )
            )
        robot = None
        if res.robot_ends is not None and res.robot_radius is not None:
            K = res.robot_ends.shape[0]
            robot = RobotOccupancyMsg(
                link_names=list(self.cell.robot.link_names),
                n_intervals=K,
                capsules=CapsulesMsg.from_arrays(res.robot_ends, res.robot_radius),
                verified=res.verified,
            )
        msg = OccupancyMsg(seq=self.pub_occ.next_seq(), stamp_s=now, humans=humans, robot=robot)
        return self._mode_display(msg, res)

    def _mode_display(self, msg: OccupancyMsg, res: CycleResult) -> OccupancyMsg:
        """Add the PFL contacts and link energies, or the JSSA state, to a display message."""
        links = self.cell.robot.link_names
        sc = self.cell.scenario
        extra: dict[str, Any] = {}
        try:
            if res.pfl is not None:
                pfl = res.pfl
                if isinstance(self.shield, PflShield) and res.trajectory is not None:
                    pfl = self.shield.with_energies(pfl, res.trajectory)  # skipped when clear
                labels = part_labels(res.human_ids, self.shield.reach.skeleton.parts)
                shapes = link_shapes(links, sc.shield.pfl.link_shapes)
                extra["contacts"] = pfl_contacts(pfl, links, labels)
                extra["links"] = pfl_links(pfl, links, labels, shapes)
            if res.jssa is not None:
                extra["jssa"] = jssa_state(res.jssa, links, sc.shield.jssa.d_min_m)
        except (SaraError, ValueError, IndexError) as e:  # display only: never stop the loop
            self.errors("display details dropped", str(e))
            return msg
        return msg.model_copy(update=extra) if extra else msg

    def scenario_msg(self, now: float) -> ScenarioStateMsg:
        return ScenarioStateMsg(
            seq=self.pub_scenario.next_seq(),
            stamp_s=now,
            cell=self.name,
            revision=self.scenario_revision,
            scenario=self.cell.scenario.model_dump(mode="json"),
        )

    def status_msg(self, now: float, state: str) -> StatusMsg:
        cu = np.array(self.cycle_us) if self.cycle_us else None
        return StatusMsg(
            seq=self.pub_status.next_seq(),
            stamp_s=now,
            cell=self.name,
            state=state,  # type: ignore[arg-type]
            scenario=self.cell.scenario.name,
            uptime_s=max(now - self.started, 0.0),
            humans=sorted(self.presence.tracks),
            cycle_time_p50_us=None if cu is None else float(np.median(cu)),
            cycle_time_p99_us=None if cu is None else float(np.percentile(cu, 99)),
            config_sha256=self.cell.checksum,
        )

    def run(self, duration_s: float | None = None) -> None:
        """Cycle at the scenario's rate until ``stop_event`` is set (or ``duration_s``)."""
        t_end = None if duration_s is None else time.monotonic() + duration_s
        next_t = time.monotonic()
        self.overruns = 0
        while not self.stop_event.is_set():
            mono = time.monotonic()
            if t_end is not None and mono >= t_end:
                break
            self.step(time.time())  # never raises (a failed cycle is a fault cycle)
            next_t += self.shield.settings.dt_s
            delay = next_t - time.monotonic()
            # never a busy loop: under SCHED_FIFO an overrunning worker would otherwise keep its
            # CPU from every normally scheduled thread (zenoh I/O included)
            time.sleep(max(delay, _MIN_SLEEP_S))
            if delay < -self.shield.settings.dt_s:
                self.overruns += 1
                next_t = time.monotonic()
        self.pub_status.put(self.status_msg(time.time(), "stopping"))
        self.builder.close()
        self.release()

    def release(self) -> None:
        """Give the cell up (another worker may claim it)."""
        if self.token is not None:
            try:
                self.token.undeclare()
            except Exception:  # noqa: BLE001 - a closed session has released it already
                pass
            self.token = None


def _id_in(key_expr: str, kind: str) -> str | None:
    """The id in a key of ``kind`` (a refused message's key), or None when it is not one."""
    try:
        k = keys.parse_key(key_expr)
    except SaraError:
        return None
    return k.human_id if k.kind == kind else None


def main(argv: list[str] | None = None) -> int:
    return process_main("worker", "run one cell worker", CellWorker, argv, state=True)


if __name__ == "__main__":
    sys.exit(main())
