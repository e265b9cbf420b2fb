"""The dashboard process's link to a cell: bus messages in, :class:`DisplayFrame` out, and the
scenario editing that goes back to the worker (validated here, applied only when the worker
accepts it: never half-applied).

Editing: pick a scenario, switch the safety mode (SSM / PFL / JSSA), change any field in the
parameter panel, drag environment boxes, people's start positions and the robot's task waypoints
(the tool frame's pose; inverse kinematics from the old waypoint, :mod:`sara_app.robot.ik`) with
gizmos, save as a new scenario file. Every change is validated as a whole scenario
(:func:`sara_app.scenario.parse_scenario` + robot checks), sent on ``sara/<cell>/params`` and
kept only if the worker's ``params/ack`` accepts it; an unreachable waypoint pose is refused
before anything is sent.

Display: PFL contacts colour the occupancy capsule (interval, link) where each contact is first
possible and the body part, by contact class; link energies go to the panel's table; the JSSA
state to the status table, its critical pair to a line.
"""

from __future__ import annotations

import copy
import logging
import threading
import time
import uuid
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from sara_app.bus import keys
from sara_app.bus.codec import Decoder
from sara_app.bus.messages import (
    ContactMsg,
    HumanOccupancyMsg,
    JssaMsg,
    LinkEnergyMsg,
    OccupancyMsg,
    ParamsAckMsg,
    ParamsMsg,
    RobotCommandMsg,
    ScenarioStateMsg,
    VerdictMsg,
)
from sara_app.bus.session import Bus
from sara_app.cell import base_pose
from sara_app.dashboard.capsules import rotation_to_wxyz
from sara_app.dashboard.frame import (
    CONTACT_CODES,
    ContactParts,
    DisplayFrame,
    EnvBoxes,
    HumanDisplay,
    LinkEnergy,
)
from sara_app.dashboard.viewer import Dashboard
from sara_app.errors import SaraError, ScenarioError, UnknownNameError
from sara_app.human.skeleton import skeleton
from sara_app.robot.ik import end_effector_frame, pose_from_wxyz, solve_ik
from sara_app.robot.model import RobotModel, load_robot
from sara_app.safety.threshold_audit import AuditLog
from sara_app.scenario import (
    SAFETY_MODES,
    Scenario,
    check_against_robot,
    load_scenario,
    parse_scenario,
    save_scenario,
    scenario_names,
)

log = logging.getLogger("sara_app.dashboard")
_EDIT_EXCLUDE = ("schema_version", "name", "description")
_BONES = skeleton("full").part_joints[
    skeleton("full").part_joints[:, 0] != skeleton("full").part_joints[:, 1]
]


PART_RADIUS_M = 0.07
"""Radius of the capsule that highlights a body part in possible contact (display only)."""


def contact_class_grid(
    contacts: list[ContactMsg], link_names: list[str], n_intervals: int
) -> np.ndarray:
    """``(K, L)`` int8 ``CONTACT_*`` values: a contact at interval ``k`` on a link marks capsule
    ``(k, link)``; several contacts on one capsule: the most constrained class (self > env >
    unconstrained). Contacts naming an unknown link or an interval beyond ``K`` are skipped."""
    grid = np.zeros((n_intervals, len(link_names)), dtype=np.int8)
    index = {name: i for i, name in enumerate(link_names)}
    for c in contacts:
        i = index.get(c.link)
        if i is not None and c.interval < n_intervals:
            grid[c.interval, i] = max(grid[c.interval, i], CONTACT_CODES[c.kind])
    return grid


def contact_parts_of(
    contacts: list[ContactMsg], humans: list[HumanOccupancyMsg]
) -> ContactParts | None:
    """The body parts in possible contact as capsules between each part's end joints (most
    constrained class per part); parts of unknown humans or names are skipped."""
    classes: dict[tuple[str, str], int] = {}
    for c in contacts:
        key = (c.human_id, c.body_part)
        classes[key] = max(classes.get(key, 0), CONTACT_CODES[c.kind])
    if not classes:
        return None
    by_id = {h.id: h for h in humans}
    ends, codes = [], []
    for (hid, part), code in classes.items():
        h = by_id.get(hid)
        if h is None:
            continue
        sk = skeleton(h.kind)
        if part not in sk.parts:
            continue
        y = np.asarray(h.joints_m).reshape(-1, 3)
        ends.append(y[sk.part_joints[sk.parts.index(part)]])
        codes.append(code)
    if not ends:
        return None
    return ContactParts(np.stack(ends), np.full(len(ends), PART_RADIUS_M), np.array(codes))


def link_rows(links: list[LinkEnergyMsg]) -> list[LinkEnergy]:
    return [
        LinkEnergy(
            e.link,
            e.energy_j,
            e.limit_j,
            e.margin_j,
            e.human_id,
            e.body_part,
            e.contact,
            e.shape,
        )
        for e in links
    ]


def jssa_display(j: JssaMsg | None) -> tuple[dict[str, Any] | None, np.ndarray | None]:
    """The status entry of a JSSA state and its critical pair ``(2, 3)`` (robot point, other
    point; None when either is missing)."""
    if j is None:
        return None, None
    status = j.model_dump(exclude={"robot_point_m", "other_point_m"})
    pair = None
    if j.robot_point_m is not None and j.other_point_m is not None:
        pair = np.array([j.robot_point_m, j.other_point_m])
    return status, pair


def _on_release(gizmo: Any, callback: Any) -> None:
    """Call ``callback(event)`` when the user lets go of ``gizmo`` (drag phase "end")."""

    def handler(event: Any) -> None:
        if getattr(event, "phase", "end") == "end":
            callback(event)

    gizmo.on_update(handler)


def verdict_status(v: VerdictMsg, cycle_us: np.ndarray) -> dict[str, Any]:
    """The status entries of a verdict (keys documented on :class:`DisplayFrame`);
    ``cycle_us (n,)``: recent cycle times [us] for the percentiles."""
    return {
        "mode": v.mode,
        "safety_mode": v.safety_mode,
        "min_distance_m": v.min_distance_m,
        "cycle_p50_us": float(np.median(cycle_us)) if cycle_us.size else None,
        "cycle_p99_us": float(np.percentile(cycle_us, 99)) if cycle_us.size else None,
        "skeleton_age_ms": {k: 1e3 * a for k, a in v.skeleton_age_s.items()},
        "dropped": dict(v.dropped),
        "models": dict(v.results),
        "faults": list(v.faults),
        "intervened": v.intervened,
        "speed_scale": v.speed_scale,
        "jssa": None,
    }


def occupancy_into(frame: DisplayFrame, occ: OccupancyMsg) -> None:
    """Fill ``frame`` with an occupancy message: humans, robot occupancy (its verdict), PFL
    contact classes, body parts in contact and link energies, the JSSA state and pair."""
    for h in occ.humans:
        models = {name: caps.arrays() for name, caps in h.models.items()}
        y = np.asarray(h.joints_m).reshape(-1, 3)
        frame.humans.append(HumanDisplay(h.id, y, _BONES, models))
    if occ.robot is not None:
        r = occ.robot
        e, rad = r.capsules.arrays()
        K, L = r.n_intervals, len(r.link_names)
        frame.robot_ends, frame.robot_radius = e.reshape(K, L, 2, 3), rad.reshape(K, L)
        frame.verified = r.verified
        frame.contact_class = contact_class_grid(occ.contacts, r.link_names, K)
    frame.contact_parts = contact_parts_of(occ.contacts, occ.humans)
    frame.links = link_rows(occ.links)
    jssa, frame.critical_pair = jssa_display(occ.jssa)
    frame.status["jssa"] = jssa
    frame.critical_active = bool(jssa and jssa["active"])


def boxes_of(sc: Scenario) -> EnvBoxes | None:
    if not sc.environment:
        return None
    T = np.stack([base_pose(b.center_m, b.rpy_rad) for b in sc.environment])
    half = np.array([b.size_m for b in sc.environment]) * 0.5
    return EnvBoxes(T, half)


class CellView:
    """Feeds one :class:`Dashboard` from one cell's messages; owns the scenario being edited."""

    def __init__(
        self,
        cell: str,
        bus: Bus,
        dashboard: Dashboard,
        scenario: Scenario,
        scenarios_folder: Path,
        ack_timeout_s: float = 5.0,
        audit: AuditLog | str | Path | None = None,
    ) -> None:
        """``audit``: the threshold audit log (or its path; None: the default path shared with
        the API) for the dashboard's threshold editor tab."""
        self.cell = keys.check_name("cell", cell)
        self.bus, self.dash = bus, dashboard
        self.scenario = scenario
        self.folder = Path(scenarios_folder)
        self.ack_timeout_s = ack_timeout_s
        dec = Decoder()
        self.sub_occ = bus.subscribe(keys.occupancy_key(cell), dec)
        self.sub_verdict = bus.subscribe(keys.verdict_key(cell), dec)
        self.sub_cmd = bus.subscribe(keys.robot_command_key(cell), dec)
        self.sub_ack = bus.subscribe(keys.params_ack_key(cell), dec, fifo=True)
        self.sub_scenario = bus.subscribe(keys.scenario_key(cell), dec)
        self.scenario_revision: int | None = None
        self.pub_params = bus.publisher(keys.params_key(cell))
        self.q: np.ndarray | None = None
        self.occ: OccupancyMsg | None = None
        self.verdict: VerdictMsg | None = None
        self.cycle_us: deque[float] = deque(maxlen=1000)
        self.gizmos: list[Any] = []
        self._seq = 0
        self._robot_key: tuple[Any, ...] | None = None
        self._robot_model: RobotModel | None = None
        self.audit = audit
        self.thresholds: Any = None
        self._ack_lock = threading.Lock()
        self._late: tuple[str, Scenario] | None = None  # (request id, scenario) unanswered

    # -- live view ---------------------------------------------------------------------------

    def poll(self) -> DisplayFrame | None:
        """Drain the bus; the frame to draw (None until the worker has spoken)."""
        for d in self.sub_cmd.drain().messages:
            if isinstance(d.msg, RobotCommandMsg):
                self.q = np.asarray(d.msg.q)
        for d in self.sub_verdict.drain().messages:
            if isinstance(d.msg, VerdictMsg):
                self.verdict = d.msg
                self.cycle_us.append(d.msg.cycle_time_us)
        for d in self.sub_occ.drain().messages:
            if isinstance(d.msg, OccupancyMsg):
                self.occ = d.msg
        self._late_answer()
        self._follow_worker()
        if self.q is None or self.verdict is None:
            return None
        return self.frame()

    def frame(self) -> DisplayFrame:
        """The frame of the latest verdict, robot command and occupancy."""
        if self.q is None or self.verdict is None:
            raise ScenarioError("no verdict and robot command received yet")
        v = self.verdict
        frame = DisplayFrame(
            t_s=v.stamp_s,
            q=self.q,
            verified=v.mode != "failsafe",
            status=verdict_status(v, np.array(self.cycle_us)),
            boxes=boxes_of(self.scenario),
        )
        if self.occ is not None:
            occupancy_into(frame, self.occ)
        return frame

    # -- editing -------------------------------------------------------------------------------

    def editable(self) -> dict[str, Any]:
        data = self.scenario.model_dump(mode="json")
        return {k: v for k, v in data.items() if k not in _EDIT_EXCLUDE}

    def send(self, data: dict[str, Any]) -> Scenario:
        """Validate ``data`` as a whole scenario, send it, wait for the worker's answer; the new
        scenario on acceptance, :class:`ScenarioError` with the reason otherwise."""
        sc = parse_scenario(data, "edited scenario")
        check_against_robot(sc)
        rid = uuid.uuid4().hex[:16]
        with self._ack_lock:
            self._late = None
            self.sub_ack.drain()
            msg = ParamsMsg(
                seq=self._next_seq(),
                stamp_s=time.time(),
                request_id=rid,
                scenario=sc.model_dump(mode="json"),
            )
            if not self.pub_params.put(msg):
                raise ScenarioError("the scenario could not be sent to the worker (bus error)")
            t_end = time.monotonic() + self.ack_timeout_s
            while time.monotonic() < t_end:
                for d in self.sub_ack.drain().messages:
                    if isinstance(d.msg, ParamsAckMsg) and d.msg.request_id == rid:
                        if not d.msg.accepted:
                            raise ScenarioError(f"the worker refused it: {d.msg.reason}")
                        self.scenario = sc
                        return sc
                time.sleep(0.01)
            self._late = (rid, sc)
        raise ScenarioError(
            f"the worker did not answer within {self.ack_timeout_s} s (if it accepts the edit "
            "later, the view follows)"
        )

    def _next_seq(self) -> int:
        # clock-based, like the API's: both publish on the params key, the worker keeps order
        self._seq = max(self._seq + 1, time.time_ns() // 1000)
        return self._seq

    def _follow_worker(self) -> None:
        """Adopt the scenario the worker announces when it differs from ours (an edit made over
        the API or by another dashboard), so our next edit builds on what the cell runs."""
        msgs = [d.msg for d in self.sub_scenario.drain().messages]
        state = next((m for m in reversed(msgs) if isinstance(m, ScenarioStateMsg)), None)
        if state is None or not self._ack_lock.acquire(blocking=False):
            return
        try:
            if state.scenario == self.scenario.model_dump(mode="json"):
                self.scenario_revision = state.revision
                return
            try:
                sc = parse_scenario(state.scenario, "the worker's scenario")
            except ScenarioError as e:
                log.warning("the worker announced a scenario this view cannot read: %s", e)
                return
            self.scenario, self.scenario_revision = sc, state.revision
        finally:
            self._ack_lock.release()
        self.refresh_panels()

    def _late_answer(self) -> None:
        """Follow the worker when it accepts an edit after :meth:`send` gave up waiting."""
        if self._late is None or not self._ack_lock.acquire(blocking=False):
            return
        try:
            late, accepted = self._late, False
            for d in self.sub_ack.drain().messages if late is not None else ():
                if isinstance(d.msg, ParamsAckMsg) and d.msg.request_id == late[0]:
                    self._late, accepted = None, d.msg.accepted
                    if accepted:
                        self.scenario = late[1]
        finally:
            self._ack_lock.release()
        if accepted:
            self.refresh_panels()
            if self.dash.panels is not None:
                self.dash.panels.show_message("the worker accepted the last edit late: applied")

    def select(self, name: str) -> None:
        sc = load_scenario(name, self.folder)
        self.send(sc.model_dump(mode="json"))
        self.refresh_panels()

    def set_mode(self, mode: str) -> None:
        """Switch the cell's safety mode (one of ``ssm``, ``pfl``, ``jssa``) through the
        validated edit path; :class:`ScenarioError` if the worker refuses it."""
        if mode not in SAFETY_MODES:
            raise UnknownNameError("safety mode", mode, SAFETY_MODES)
        data = self.scenario.model_dump(mode="json")
        data["shield"]["mode"] = mode
        self.send(data)
        self.refresh_panels()

    def edit(self, params: dict[str, Any]) -> None:
        data = self.scenario.model_dump(mode="json")
        data.update(params)
        self.send(data)
        self.refresh_panels()

    def save_as(self, name: str) -> Path:
        if name in scenario_names(self.folder):
            raise ScenarioError(f"a scenario named {name!r} exists; choose a new name")
        data = self.scenario.model_dump(mode="json")
        data["name"] = name
        sc = parse_scenario(data, "save as")
        path = save_scenario(sc, self.folder / f"{name}.json")
        if self.dash.panels is not None:
            self.dash.panels.set_scenarios(list(scenario_names(self.folder)), name)
        return path

    def refresh_panels(self) -> None:
        """Show the accepted scenario in the panels (and connect the safety-mode dropdown)."""
        panels = self.dash.panels
        if panels is not None:
            panels.on_set_mode = self.set_mode
            panels.set_safety_mode(self.scenario.shield.mode)
            panels.set_scenarios(list(scenario_names(self.folder)), self.scenario.name)
            panels.set_params(self.editable())
            self._attach_thresholds()
        self.add_gizmos()

    def _attach_thresholds(self) -> None:
        """The threshold editor (:mod:`sara_app.dashboard.thresholds_panel`) in its own tab,
        sending through :meth:`send`; refreshed when the scenario changes."""
        if self.thresholds is not None:
            self.thresholds.select()
            return
        panels, server = self.dash.panels, self.dash.server
        if panels is None or server is None:
            return
        from sara_app.dashboard.thresholds_panel import attach

        try:
            audit = self.audit if isinstance(self.audit, AuditLog) else AuditLog(self.audit)
        except SaraError as e:
            log.warning("no threshold editor: %s", e)
            return
        with panels.add_tab("Thresholds"):
            self.thresholds = attach(
                server.gui, lambda: self.scenario, self._send_and_show, audit, self.cell
            )

    def _send_and_show(self, data: dict[str, Any]) -> Scenario:
        sc = self.send(data)
        if self.dash.panels is not None:
            self.dash.panels.set_params(self.editable())
        return sc

    # -- robot waypoints -----------------------------------------------------------------------

    def robot(self) -> RobotModel:
        """The scenario's robot at its base pose (reloaded when the robot or base changes)."""
        r = self.scenario.robot
        key = (r.name, tuple(r.base_xyz_m), tuple(r.base_rpy_rad))
        if self._robot_model is None or key != self._robot_key:
            T = base_pose(r.base_xyz_m, r.base_rpy_rad)
            self._robot_model = load_robot(r.name, T_world_base=T)
            self._robot_key = key
        return self._robot_model

    def waypoint_poses(self) -> np.ndarray:
        """World poses ``(W, 4, 4)`` of the tool frame at the task's waypoints."""
        robot = self.robot()
        frame = end_effector_frame(robot)
        wps = self.scenario.task.waypoints_rad
        return np.stack([robot.frame_pose(np.asarray(q, dtype=float), frame) for q in wps])

    def move_waypoint(self, i: int, T_world_target: np.ndarray) -> np.ndarray:
        """Solve waypoint ``i`` for a tool pose ``T_world_target (4, 4)`` (warm start: the old
        waypoint) and send the edited scenario; the new joint positions. Raises
        :class:`ScenarioError` (nothing sent) when the pose is out of reach."""
        wps = self.scenario.task.waypoints_rad
        if not 0 <= i < len(wps):
            raise ScenarioError(f"waypoint {i} does not exist; the task has {len(wps)}")
        robot = self.robot()
        res = solve_ik(robot, T_world_target, np.asarray(wps[i], dtype=float))
        if not res.converged:
            p = np.round(np.asarray(T_world_target)[:3, 3], 3).tolist()
            raise ScenarioError(
                f"waypoint {i}: the tool pose at {p} m is out of reach of the {robot.name} "
                f"(closest found: {1e3 * res.position_error_m:.1f} mm and "
                f"{np.degrees(res.rotation_error_rad):.1f} deg away); the waypoint is unchanged"
            )
        data = self.scenario.model_dump(mode="json")
        data["task"]["waypoints_rad"][i] = [float(x) for x in res.q]
        self.send(data)
        return res.q

    # -- gizmos --------------------------------------------------------------------------------

    def add_gizmos(self) -> None:
        """Drag handles for environment boxes, people's start positions and the robot's task
        waypoints (at the tool frame's pose)."""
        server = self.dash.server
        if server is None:
            return
        for g in self.gizmos:
            g.remove()
        self.gizmos = []
        self._add_waypoint_gizmos(server)
        for i, b in enumerate(self.scenario.environment):
            g = server.scene.add_transform_controls(
                f"/edit/box_{i}", scale=0.3, position=b.center_m, disable_rotations=True
            )
            _on_release(g, self._on_box_drag(i, g))
            self.gizmos.append(g)
        for i, h in enumerate(self.scenario.humans):
            pos = getattr(h, "position_m", None)
            if pos is None:
                continue
            g = server.scene.add_transform_controls(
                f"/edit/human_{i}",
                scale=0.3,
                position=(pos[0], pos[1], 0.0),
                disable_rotations=True,
                active_axes=(True, True, False),
            )
            _on_release(g, self._on_human_drag(i, g))
            self.gizmos.append(g)

    def _add_waypoint_gizmos(self, server: Any) -> None:
        try:
            poses = self.waypoint_poses()
        except (ScenarioError, ValueError) as e:  # a robot that cannot be loaded: no handles
            log.warning("no waypoint gizmos: %s", e)
            return
        wxyz = rotation_to_wxyz(poses[:, :3, :3])
        for i, T in enumerate(poses):
            g = server.scene.add_transform_controls(
                f"/edit/waypoint_{i}", scale=0.15, position=T[:3, 3], wxyz=wxyz[i]
            )
            label = server.scene.add_label(f"/edit/waypoint_{i}/label", f"waypoint {i}")
            _on_release(g, self._on_waypoint_drag(i, g))
            self.gizmos += [label, g]

    def _on_waypoint_drag(self, i: int, g: Any) -> Any:
        def cb(_event: Any) -> None:
            def apply() -> None:
                T = pose_from_wxyz(np.asarray(g.wxyz), np.asarray(g.position))
                self.move_waypoint(i, T)

            self._report(f"waypoint {i}", apply)

        return cb

    def _report(self, what: str, fn: Any) -> None:
        panels = self.dash.panels
        try:
            fn()
            if panels is not None:
                panels.show_message(f"{what}: applied")
        except (ScenarioError, ValueError) as e:
            if panels is not None:
                panels.show_message(f"{what} refused: {e}", error=True)
            self.add_gizmos()  # back to the accepted positions

    def _on_box_drag(self, i: int, g: Any) -> Any:
        def cb(_event: Any) -> None:
            def apply() -> None:
                data = self.scenario.model_dump(mode="json")
                data["environment"][i]["center_m"] = [float(x) for x in g.position]
                self.send(data)

            self._report(f"box {i}", apply)

        return cb

    def _on_human_drag(self, i: int, g: Any) -> Any:
        def cb(_event: Any) -> None:
            def apply() -> None:
                data = copy.deepcopy(self.scenario.model_dump(mode="json"))
                data["humans"][i]["position_m"] = [float(g.position[0]), float(g.position[1])]
                self.send(data)

            self._report(f"person {i}", apply)

        return cb
