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

import logging
import sys
import threading
import time
from collections import deque
from typing import Any, cast

import numpy as np

from sara_app.bus import keys
from sara_app.bus.codec import Decoder
from sara_app.bus.messages import (
    CapsulesMsg,
    HumanOccupancyMsg,
    OccupancyMsg,
    ParamsAckMsg,
    ParamsMsg,
    RobotCommandMsg,
    RobotOccupancyMsg,
    RobotStateMsg,
    ScenarioStateMsg,
    SkeletonMsg,
    StatusMsg,
    VerdictMsg,
)
from sara_app.bus.process import process_main
from sara_app.bus.session import Bus
from sara_app.cell import Cell, build_cell
from sara_app.errors import SaraError
from sara_app.human.velocity import VelocityEstimator
from sara_app.robot.trajectory import JointState
from sara_app.safety.pfl_shield import PflShield
from sara_app.safety.shield import CycleResult, HumanState, Shield
from sara_app.safety.thresholds import link_shapes
from sara_app.scenario import Scenario, check_against_robot, parse_scenario
from sara_app.worker_display import jssa_state, part_labels, pfl_contacts, pfl_links

log = logging.getLogger("sara_app.worker")
_MIN_SLEEP_S = 20e-6  # the least the loop sleeps per cycle, even when late (s)


class _Track:
    """One person: the latest accepted measurement and a velocity estimator."""

    def __init__(self, human_id: str, cell: Cell) -> None:
        J = cell.shield.reach.skeleton.n_joints
        self.estimator = VelocityEstimator(J, cell.params.delta_y_m, cell.params.a_max_mps2)
        self.state = HumanState.unmeasured(human_id, J)


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
    ) -> None:
        self.name = keys.check_name("cell", cell_name)
        self.bus = bus
        self.loop_task = loop_task
        self.display_period = 1.0 / display_hz
        self.status_period = 1.0 / status_hz
        self.cell = build_cell(scenario)
        self.tracks: dict[str, _Track] = {}
        self.extra_drops: dict[str, int] = {}
        self.measured: JointState | None = None
        self.pass_index = 0
        self.cycle_us: deque[float] = deque(maxlen=2000)
        self.started = time.time()
        self._next_display = 0.0
        self._next_status = 0.0
        self.last: CycleResult | None = None
        self.stop_event = threading.Event()
        self.decoder = Decoder()  # one set of drop counters for every input
        self.sub_skel = bus.subscribe(keys.skeleton_keys(self.name), self.decoder)
        self.sub_state = bus.subscribe(keys.robot_state_key(self.name), self.decoder)
        self.sub_params = bus.subscribe(keys.params_key(self.name), self.decoder, fifo=True)
        self.pub_cmd = bus.publisher(keys.robot_command_key(self.name))
        self.pub_verdict = bus.publisher(keys.verdict_key(self.name))
        self.pub_occ = bus.publisher(keys.occupancy_key(self.name), express=False)
        self.pub_ack = bus.publisher(keys.params_ack_key(self.name))
        self.pub_status = bus.publisher(keys.status_key(self.name))
        self.pub_scenario = bus.publisher(keys.scenario_key(self.name))
        self.scenario_revision = 0

    @property
    def shield(self) -> Shield:
        return self.cell.shield

    # -- inputs --------------------------------------------------------------------------------

    def _drop(self, reason: str) -> None:
        self.extra_drops[reason] = self.extra_drops.get(reason, 0) + 1

    def _ingest_skeleton(self, human_id: str, msg: SkeletonMsg) -> None:
        if msg.kind != "full":
            self._drop("unsupported_kind")  # the cell verifies full-body skeletons
            return
        p = self.cell.params
        if msg.position_uncertainty_m is not None and msg.position_uncertainty_m > p.delta_y_m:
            self._drop("uncertainty_above_params")
            return
        track = self.tracks.get(human_id)
        if track is None:
            track = self.tracks[human_id] = _Track(human_id, self.cell)
        y, v = msg.to_arrays()
        try:
            v_est, dv_est = track.estimator.update(msg.stamp_s, y)
        except SaraError:
            self._drop("stamp_not_advancing")
            return
        st = track.state
        if v is not None:
            unc = msg.velocity_uncertainty_mps
            st.v = v
            st.dv = np.full(len(y), p.delta_v_mps if unc is None else max(unc, p.delta_v_mps))
        else:
            st.v, st.dv = v_est.copy(), dv_est.copy()
        st.y = y
        st.stamp_s = msg.stamp_s

    def _ingest(self) -> None:
        for d in self.sub_skel.drain().messages:
            if isinstance(d.msg, SkeletonMsg) and d.key.human_id:
                self._ingest_skeleton(d.key.human_id, d.msg)
        for d in self.sub_state.drain().messages:
            if isinstance(d.msg, RobotStateMsg):
                self.measured = JointState(
                    q=np.asarray(d.msg.q), v=np.asarray(d.msg.q_dot), a=np.zeros(len(d.msg.q))
                )
        for d in self.sub_params.drain().messages:
            if isinstance(d.msg, ParamsMsg):
                ok, reason = self.apply(d.msg.scenario)
                if ok:  # the new state first: an editor that sees the ack can build on it
                    self.pub_scenario.put(self.scenario_msg(time.time()))
                self.pub_ack.put(
                    ParamsAckMsg(
                        seq=self.pub_ack.next_seq(),
                        stamp_s=time.time(),
                        request_id=d.msg.request_id,
                        accepted=ok,
                        reason=reason,
                    )
                )

    def apply(self, data: dict) -> tuple[bool, str]:
        """Validate a scenario and apply it live; never half-applied. Returns (accepted, why)."""
        try:
            sc = parse_scenario(data, "params message")
            check_against_robot(sc)
            new = build_cell(sc)
        except SaraError as e:
            return False, str(e)
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
        self.tracks.clear()  # velocity bounds depend on the parameters
        self.scenario_revision += 1
        return True, ""

    # -- the cycle -----------------------------------------------------------------------------

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
            log.warning("task replan failed: %s", e)

    def step(self, now: float) -> CycleResult:
        self._ingest()
        humans = [t.state for t in self.tracks.values()]
        res = self.shield.cycle(now, humans, self.measured)
        self.last = res
        self.cycle_us.append(res.cycle_time_us)
        self._advance_task()
        self._publish(now, res)
        return res

    def _publish(self, now: float, res: CycleResult) -> None:
        c = res.command
        self.pub_cmd.put(
            RobotCommandMsg(
                seq=self.pub_cmd.next_seq(),
                stamp_s=now,
                q=c.q.tolist(),
                q_dot=c.v.tolist(),
                q_ddot=c.a.tolist(),
                mode=cast(Any, res.mode),
            )
        )
        dropped = dict(self.decoder.counts)
        for k, v in self.extra_drops.items():
            dropped[k] = dropped.get(k, 0) + v
        self.pub_verdict.put(
            VerdictMsg(
                seq=self.pub_verdict.next_seq(),
                stamp_s=now,
                cell=self.name,
                safety_mode=cast(Any, res.safety_mode),
                mode=cast(Any, res.mode),
                results=res.model_free,
                skeleton_age_s=res.ages_s,
                min_distance_m=res.min_distance_m,
                cycle_time_us=res.cycle_time_us,
                faults=res.faults[:8],
                dropped=dropped,
                intervened=res.intervened,
                speed_scale=res.speed_scale if res.safety_mode == "pfl" else None,
            )
        )
        if now >= self._next_display:
            self._next_display = now + self.display_period
            self.pub_occ.put(self.occupancy_msg(now, res))
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
        for t in self.tracks.values():
            st = t.state
            if st.stamp_s is None:
                continue
            age = max(now - st.stamp_s, 0.0)
            models = {}
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
                except SaraError:
                    continue
                if np.all(np.isfinite(o.radius)):
                    models[name] = CapsulesMsg.from_arrays(o.ends[0, 0], o.radius[0, 0])
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
            log.warning("display details dropped: %s", e)
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
            humans=sorted(self.tracks),
            cycle_time_p50_us=None if cu is None else float(np.median(cu)),
            cycle_time_p99_us=None if cu is None else float(np.percentile(cu, 99)),
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
            try:
                self.step(time.time())
            except Exception:  # noqa: BLE001 - last line of defence: brake, report, go on
                log.exception("worker cycle failed; braking on the held failsafe")
                self.shield.brake_step()
            next_t += self.shield.settings.dt_s
            delay = next_t - time.monotonic()
            # never a busy loop: under SCHED_FIFO an overrunning worker would otherwise keep its
            # CPU from every normally scheduled thread (zenoh I/O included)
            time.sleep(max(delay, _MIN_SLEEP_S))
            if delay < -self.shield.settings.dt_s:
                self.overruns += 1
                next_t = time.monotonic()
        self.pub_status.put(self.status_msg(time.time(), "stopping"))


def main(argv: list[str] | None = None) -> int:
    return process_main("worker", "run one cell worker", CellWorker, argv)


if __name__ == "__main__":
    sys.exit(main())
