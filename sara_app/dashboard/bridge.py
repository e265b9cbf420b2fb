"""The dashboard process's link to a cell: bus messages in, :class:`DisplayFrame` out, and the
scenario editing that goes back to the worker (validated here, applied only when the worker
accepts it: never half-applied).

Editing: pick a scenario, switch the safety mode (SSM / PFL / JSSA), change any field in the
parameter panel, drag environment boxes, people's start positions and the robot's task waypoints
(the tool frame's pose) with gizmos (:mod:`sara_app.dashboard.gizmos`), save as a new scenario
file. Every change is validated as a whole scenario
(:func:`sara_app.scenario.parse_scenario` + robot checks), sent on ``sara/<cell>/params`` and
kept only if the worker's ``params/ack`` accepts it; an unreachable waypoint pose is refused
before anything is sent.

Display (:mod:`sara_app.dashboard.from_messages`): PFL contacts colour the occupancy capsule
(interval, link) where each contact is first possible and the body part, by contact class; link
energies go to the panel's table; the JSSA state to the status table, its critical pair to a
line.
"""

from __future__ import annotations

import logging
import threading
import time
import uuid
from collections import deque
from pathlib import Path
from typing import Any, Protocol, cast

import numpy as np

from sara_app.bus import keys
from sara_app.bus.codec import Decoder
from sara_app.bus.messages import (
    OccupancyMsg,
    ParamsAckMsg,
    ParamsMsg,
    ReplanMsg,
    RobotCommandMsg,
    ScenarioStateMsg,
    StatusMsg,
    VerdictMsg,
)
from sara_app.bus.session import Bus
from sara_app.dashboard.frame import DisplayFrame
from sara_app.dashboard.from_messages import boxes_of, occupancy_into, verdict_status
from sara_app.dashboard.gizmos import GizmoEditing
from sara_app.dashboard.human_set_text import human_set_markdown
from sara_app.dashboard.panels import CONFIRM_HOW
from sara_app.dashboard.viewer import Dashboard
from sara_app.dashboard.whatif_panel import WhatIfHooks, WhatIfPanels
from sara_app.errors import SaraError, ScenarioError, UnknownNameError, WorkerTimeoutError
from sara_app.geometry.poses import pose_from_xyz_rpy
from sara_app.ops.audit import AuditLog, default_audit_path
from sara_app.ops.client_edits import check_client_edit, check_no_raise
from sara_app.ops.jobs import JobRunner
from sara_app.ops.loosening import apply_checked
from sara_app.robot.model import RobotModel
from sara_app.safety.settings import SAFETY_MODES
from sara_app.scenario import (
    Scenario,
    check_against_robot,
    load_scenario,
    parse_scenario,
    save_scenario,
    scenario_names,
)

log = logging.getLogger("sara_app.dashboard")
_EDIT_EXCLUDE = ("schema_version", "name", "description")
VERDICTS_KEPT = 256
"""Verdicts kept to find the one of an occupancy's cycle (about 0.5 s at 500 Hz; occupancies
come at 15 Hz)."""


class VerdictSource(Protocol):
    """Where a view may take a cell's verdicts from instead of its own subscription: the API's
    registry in the same process (:meth:`~sara_app.api.registry.CellRegistry.verdicts_after`),
    which decodes each of them anyway."""

    def verdicts_after(self, name: str, seen: int) -> tuple[list[VerdictMsg], int]: ...


class CellView(GizmoEditing):
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
        verdicts: VerdictSource | None = None,
    ) -> None:
        """``audit``: the threshold audit log (or its path; None: the default path shared with
        the API) for the dashboard's threshold editor tab; ``verdicts``: where the cell's
        verdicts come from (None: a subscription of this view's own)."""
        self.cell = keys.check_name("cell", cell)
        self.bus, self.dash = bus, dashboard
        self.scenario = scenario
        self.folder = Path(scenarios_folder)
        self.ack_timeout_s = ack_timeout_s
        dec = Decoder()
        self.sub_occ = bus.subscribe(keys.occupancy_key(cell), dec)
        self.verdict_source = verdicts
        self.verdicts_seen = 0
        own = verdicts is None
        self.sub_verdict = bus.subscribe(keys.verdict_key(cell), dec) if own else None
        self.sub_cmd = bus.subscribe(keys.robot_command_key(cell), dec)
        # a ring: a view that sends nothing never reads the answers, and a full FIFO held
        # its whole link (no verdict reached the view after 256 answers to others' requests)
        self.sub_ack = bus.subscribe(keys.params_ack_key(cell), dec)
        self.sub_scenario = bus.subscribe(keys.scenario_key(cell), dec)
        self.sub_status = bus.subscribe(keys.status_key(cell), dec)
        self.worker_status: StatusMsg | None = None
        self.scenario_revision: int | None = None
        self.pub_params = bus.publisher(keys.params_key(cell))
        self.pub_replan = bus.publisher(keys.robot_replan_key(cell))
        self.q: np.ndarray | None = None
        self.occ: OccupancyMsg | None = None
        self.verdict: VerdictMsg | None = None
        self.recent: deque[VerdictMsg] = deque(maxlen=VERDICTS_KEPT)
        """The latest verdicts: the one of the occupancy's own cycle is shown with it."""
        self.cycle_us: deque[float] = deque(maxlen=1000)
        self.gizmos: list[Any] = []
        self._seq = 0
        self._robot_key: tuple[Any, ...] | None = None
        self._robot_model: RobotModel | None = None
        self.audit = audit
        self.thresholds: Any = None
        self.changes: Any = None  # the Changes tab (ChangesPanel), once the panels exist
        self._ack_lock = threading.Lock()
        self._late: tuple[str, Scenario] | None = None  # (request id, scenario) unanswered

    # -- live view ---------------------------------------------------------------------------

    def poll(self) -> DisplayFrame | None:
        """Drain the bus; the frame to draw (None until the worker has spoken)."""
        # the newest command only: the view draws its set point, and decoding each of the 500
        # a second (a whole verified stop apiece) starved this low-priority process's threads
        for d in self.sub_cmd.drain_latest().messages:
            if isinstance(d.msg, RobotCommandMsg):
                self.q = np.asarray(d.msg.q)
        for v in self._new_verdicts():
            self.verdict = v
            self.recent.append(v)
            self.cycle_us.append(v.cycle_time_us)
        for d in self.sub_occ.drain().messages:
            if isinstance(d.msg, OccupancyMsg):
                self.occ = d.msg
        for d in self.sub_status.drain().messages:
            if isinstance(d.msg, StatusMsg):
                self.worker_status = d.msg
        self._late_answer()
        self._follow_worker()
        if self.changes is not None:
            self.changes.refresh_if_due(time.monotonic())
        if self.q is None or self.verdict is None:
            return None
        return self.frame()

    def _new_verdicts(self) -> list[VerdictMsg]:
        """The verdicts since the last call: from this view's own subscription, or (``serve``)
        from the source that shares one subscription among the views."""
        if self.sub_verdict is not None:
            msgs = self.sub_verdict.drain().messages
            return [d.msg for d in msgs if isinstance(d.msg, VerdictMsg)]
        source = cast(VerdictSource, self.verdict_source)  # set when there is no subscription
        new, self.verdicts_seen = source.verdicts_after(self.cell, self.verdicts_seen)
        return new

    def waiting_status(self) -> dict[str, Any]:
        """The status table's entries before the first verdict: what the worker says it is
        doing (``starting: building the cell ...``), or that nothing has reported yet."""
        st = self.worker_status
        if st is not None and st.state == "starting":
            return {"mode": f"starting: {st.detail}" if st.detail else "starting"}
        return {"mode": "waiting for the cell worker's first verdict"}

    def frame(self) -> DisplayFrame:
        """The frame of the latest verdict, robot command and occupancy."""
        if self.q is None or self.verdict is None:
            raise ScenarioError("no verdict and robot command received yet")
        v = self._verdict_of_occupancy() or self.verdict
        frame = DisplayFrame(
            t_s=v.stamp_s,
            q=self.q,
            verified=v.mode != "failsafe",
            status=verdict_status(v, np.array(self.cycle_us), self.worker_status),
            boxes=boxes_of(self.scenario),
        )
        if self.occ is not None:
            occupancy_into(frame, self.occ)
        return frame

    def _verdict_of_occupancy(self) -> VerdictMsg | None:
        """The verdict of the cycle the latest occupancy comes from (the worker stamps both
        with the cycle's time): the status, the colours and the PFL link table then show one
        cycle (the occupancy comes at display rate, the verdicts every cycle). None when it
        is no longer kept (the latest verdict is shown then)."""
        if self.occ is None:
            return None
        for v in reversed(self.recent):
            if v.stamp_s == self.occ.stamp_s:
                return v
        return None

    # -- editing -------------------------------------------------------------------------------

    def editable(self) -> dict[str, Any]:
        data = self.scenario.model_dump(mode="json")
        return {k: v for k, v in data.items() if k not in _EDIT_EXCLUDE}

    def send(
        self, data: dict[str, Any], action: str = "scenario", confirm: bool = False
    ) -> Scenario:
        """Validate ``data`` as a whole scenario, send it, wait for the worker's answer; the new
        scenario on acceptance, :class:`ScenarioError` with the reason otherwise,
        :class:`WorkerTimeoutError` without an answer. Only for a client that may change the
        cell (:class:`AccessError` otherwise); audited as ``action``
        (:mod:`sara_app.dashboard.access`). An edit that loosens what the verdict assumes
        (:mod:`sara_app.ops.loosening`) only with ``confirm``
        (:class:`~sara_app.ops.loosening.LooseningRefusedError` otherwise), recorded with its
        outcome either way."""
        return self.dash.access.change(
            action, lambda: self._checked(data, action, confirm), timeouts=(WorkerTimeoutError,)
        )

    def _checked(self, data: dict[str, Any], action: str, confirm: bool) -> Scenario:
        sc = self._validated(data, action)
        sc, changes, _ = apply_checked(
            self.scenario, sc, lambda confirmed: self._post(sc, confirmed), confirm=confirm,
            how_to_confirm=CONFIRM_HOW, audit=self._audit_log, cell=self.cell,
            user=self.dash.access.user(), via="dashboard", no_answer=(WorkerTimeoutError,),
        )  # fmt: skip
        if changes and self.dash.panels is not None:
            self.dash.panels.clear_confirmation()  # one confirmation, one edit
        return sc

    def confirmed(self) -> bool:
        """Whether the Scenario tab's "Confirm loosening" is ticked."""
        return self.dash.panels is not None and self.dash.panels.loosening_confirmed()

    def _audit_log(self) -> AuditLog:
        """The audit log, opened on first use when given as a path (once: each open runs the
        schema's statements)."""
        if not isinstance(self.audit, AuditLog):
            self.audit = AuditLog(self.audit)
        return self.audit

    def _validated(self, data: dict[str, Any], action: str) -> Scenario:
        """``data`` as a client's edit of the scenario in force (:mod:`sara_app.ops.client_edits`):
        no file of its choosing (a stored scenario, "load", is the server's own), no raised
        energy limit but the threshold editor's ("threshold": confirmed and audited by
        apply_edit)."""
        current = self.scenario
        if action != "load":
            check_client_edit(current.model_dump(mode="json"), data)
        sc = parse_scenario(data, "edited scenario")
        check_against_robot(sc)
        if action != "threshold":
            check_no_raise(current, sc, thresholds_path="the Thresholds tab")
        return sc

    def _post(self, sc: Scenario, confirmed: bool) -> Scenario:
        """Send ``sc`` to the worker (``confirmed``: with the user's confirmation of its
        loosenings) and wait for its answer."""
        rid = uuid.uuid4().hex[:16]
        with self._ack_lock:
            self._late = None
            self.sub_ack.drain()
            msg = ParamsMsg(
                seq=self._next_seq(),
                stamp_s=time.time(),
                request_id=rid,
                scenario=sc.model_dump(mode="json"),
                confirm=confirmed,
                user=self.dash.access.user()[:64],  # the worker's record names the sender
            )
            if not self.pub_params.put(msg):
                raise ScenarioError("the scenario could not be sent to the worker (bus error)")
            ans = self._answer(rid)
            if ans is not None:
                if not ans.accepted:
                    raise ScenarioError(f"the worker refused it: {ans.reason}")
                self.scenario = sc
                return sc
            self._late = (rid, sc)
        raise WorkerTimeoutError(
            f"the worker did not answer within {self.ack_timeout_s} s (if it accepts the edit "
            "later, the view follows)"
        )

    def _answer(self, rid: str) -> ParamsAckMsg | None:
        """The worker's answer to request ``rid`` within the answer timeout (None: none came);
        called under ``_ack_lock``."""
        t_end = time.monotonic() + self.ack_timeout_s
        while time.monotonic() < t_end:
            for d in self.sub_ack.drain().messages:
                if isinstance(d.msg, ParamsAckMsg) and d.msg.request_id == rid:
                    return d.msg
            time.sleep(0.01)
        return None

    def replan(self, q_rad: list[float]) -> None:
        """Have the worker plan from where the robot stands, which the operator confirmed is
        ``q_rad`` (the position the Status tab showed: the controller's word is not enough,
        :mod:`sara_app.runtime.robot_link`); recorded in the audit's robot actions with its
        outcome (the log is opened first: an action that cannot be recorded is not sent).
        :class:`ScenarioError` with the worker's reason when it refuses,
        :class:`WorkerTimeoutError` without an answer; only for a client that may change the
        cell."""
        self.dash.access.change(
            "replan", lambda: self._replan(list(q_rad)), timeouts=(WorkerTimeoutError,)
        )

    def _replan(self, q_rad: list[float]) -> None:
        audit, user = self._audit_log(), self.dash.access.user()
        reason = "confirmed in the dashboard's Status tab"

        def record(outcome: str, detail: str = "") -> None:
            audit.record_robot_action(cell=self.cell, q_rad=q_rad, user=user, reason=reason,
                                      outcome=outcome, detail=detail, via="dashboard")  # fmt: skip

        rid = f"replan-{uuid.uuid4().hex[:16]}"
        msg = ReplanMsg(seq=self._next_seq(), stamp_s=time.time(), request_id=rid, q=q_rad,
                        user=user[:64], reason=reason)  # fmt: skip
        with self._ack_lock:
            self.sub_ack.drain()
            sent = self.pub_replan.put(msg)
            ans = self._answer(rid) if sent else None
        if not sent:
            record("refused", "bus error")
            raise ScenarioError("the re-plan could not be sent to the worker (bus error)")
        if ans is None:
            why = f"the worker did not answer within {self.ack_timeout_s} s"
            record("no_answer", why)
            raise WorkerTimeoutError(why)
        if not ans.accepted:
            record("refused", ans.reason)
            raise ScenarioError(f"the worker refused it: {ans.reason}")
        record("applied")

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
        """Load the stored scenario ``name``: one of the server's scenarios folder, never a path
        (the dropdown offers names, but a client may send any string, and a file of its choosing
        would be read, and its content quoted in the refusal, before anything else), only for a
        client that may change the cell, audited as "load" (refused or not)."""

        def load() -> Scenario:
            names = scenario_names(self.folder)
            if name not in names:
                raise UnknownNameError("scenario", name, names)
            data = load_scenario(name, self.folder).model_dump(mode="json")
            return self._checked(data, "load", self.confirmed())

        self.dash.access.change("load", load, timeouts=(WorkerTimeoutError,))
        self.refresh_panels()

    def set_mode(self, mode: str) -> None:
        """Switch the cell's safety mode (one of ``ssm``, ``pfl``, ``jssa``) through the
        validated edit path; :class:`ScenarioError` if the worker refuses it. One audited
        change, an unknown mode (which a client may send) included."""

        def switch() -> Scenario:
            if mode not in SAFETY_MODES:
                raise UnknownNameError("safety mode", mode, SAFETY_MODES)
            data = self.scenario.model_dump(mode="json")
            data["shield"]["mode"] = mode
            return self.send(data, "safety-mode")

        self.dash.access.change("safety-mode", switch, timeouts=(WorkerTimeoutError,))
        self.refresh_panels()

    def edit(self, params: dict[str, Any]) -> None:
        data = self.scenario.model_dump(mode="json")
        data.update(params)
        self.send(data, "parameters", self.confirmed())
        self.refresh_panels()

    def edited(self, mode: str | None = None) -> dict[str, Any]:
        """The scenario in force with the Scenario tab's parameters (and safety ``mode``),
        validated (:class:`ScenarioError` if not); nothing is sent."""
        data = self.scenario.model_dump(mode="json")
        if self.dash.panels is not None:
            data.update(self.dash.panels.params())
        if mode is not None:
            data["shield"] = {**data["shield"], "mode": mode}
        return parse_scenario(data, "the edited parameters").model_dump(mode="json")

    def apply_whatif(self, data: dict[str, Any], confirm: bool = False) -> None:
        """Apply a what-if's edited scenario (the validated, audited edit path)."""
        self.send(data, "what-if", confirm)
        self.refresh_panels()

    def attach_whatif(self, jobs: JobRunner) -> WhatIfPanels | None:
        """The per-browser what-if and report folder (:mod:`~.whatif_panel`)."""
        server = self.dash.server
        if server is None:
            return None
        audit = self.audit.path if isinstance(self.audit, AuditLog) else self.audit
        robot = self.scenario.robot
        hooks = WhatIfHooks(
            current=lambda: self.scenario.model_dump(mode="json"),
            edited=self.edited,
            apply=self.apply_whatif,
            cell=self.cell,
            robot=self.scenario.robot.name,
            T_world_base=pose_from_xyz_rpy(robot.base_xyz_m, robot.base_rpy_rad),
            audit_path=Path(audit) if audit is not None else default_audit_path(),
        )
        return WhatIfPanels(server, jobs, hooks)

    def save_as(self, name: str) -> Path:
        """Save the scenario in force as a new file ``name`` (never overwrites); audited."""
        return self.dash.access.change("save-as", lambda: self._save_as(name))

    def _save_as(self, name: str) -> Path:
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
            panels.on_replan = self.replan
            panels.set_safety_mode(self.scenario.shield.mode)
            panels.set_scenarios(list(scenario_names(self.folder)), self.scenario.name)
            panels.set_params(self.editable())
            panels.set_human_set(self._human_set())
            self._attach_thresholds()
            self._attach_changes()
        self.add_gizmos()

    def _human_set(self) -> str:
        """What the scenario's human set is sound on, in words (its own record)."""
        try:
            return human_set_markdown(self.scenario.param_set())
        except SaraError as e:  # a set that cannot be read now (a file renamed meanwhile)
            return human_set_markdown(None, f"the set cannot be read: {e}")

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
            audit = self._audit_log()
        except SaraError as e:
            log.warning("no threshold editor: %s", e)
            return
        with panels.add_tab("Thresholds"):
            self.thresholds = attach(
                server.gui,
                lambda: self.scenario,
                self._send_and_show,
                audit,
                self.cell,
                who=lambda typed: self.dash.access.require("threshold", typed),
                no_answer=(WorkerTimeoutError,),
            )
        # with credentials in force the user is the signed-in one's, never a typed name
        self.thresholds.user.visible = not self.dash.access.required

    def _attach_changes(self) -> None:
        """The "Changes" tab (:mod:`sara_app.dashboard.changes_panel`): what the worker
        answered, from the audit log; refreshed from :meth:`poll`."""
        panels, server = self.dash.panels, self.dash.server
        if self.changes is not None or panels is None or server is None:
            return
        from sara_app.dashboard.changes_panel import ChangesPanel

        with panels.add_tab("Changes"):
            self.changes = ChangesPanel(server.gui, self._audit_log, self.cell)

    def _send_and_show(self, data: dict[str, Any]) -> Scenario:
        sc = self.send(data, "threshold")
        if self.dash.panels is not None:
            self.dash.panels.set_params(self.editable())
        return sc
