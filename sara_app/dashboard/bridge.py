"""The dashboard process's link to a cell: bus messages in, :class:`DisplayFrame` out, and the
scenario editing that goes back to the worker (validated here, applied only when the worker
accepts it: never half-applied).

Editing: pick a scenario, change any field in the parameter panel, drag environment boxes and
people's start positions with gizmos, save as a new scenario file. Every change is validated as
a whole scenario (:func:`sara_app.scenario.parse_scenario` + robot checks), sent on
``sara/<cell>/params`` and kept only if the worker's ``params/ack`` accepts it.
"""

from __future__ import annotations

import copy
import logging
import time
import uuid
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

from sara_app.bus import keys
from sara_app.bus.codec import Decoder
from sara_app.bus.messages import (
    OccupancyMsg,
    ParamsAckMsg,
    ParamsMsg,
    RobotCommandMsg,
    VerdictMsg,
)
from sara_app.bus.session import Bus
from sara_app.cell import base_pose
from sara_app.dashboard.frame import DisplayFrame, EnvBoxes, HumanDisplay
from sara_app.dashboard.viewer import Dashboard
from sara_app.errors import ScenarioError
from sara_app.human.skeleton import skeleton
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
_BONES = skeleton("full").part_joints[
    skeleton("full").part_joints[:, 0] != skeleton("full").part_joints[:, 1]
]


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
        ack_timeout_s: float = 3.0,
    ) -> None:
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
        self.pub_params = bus.publisher(keys.params_key(cell))
        self.q: np.ndarray | None = None
        self.occ: OccupancyMsg | None = None
        self.verdict: VerdictMsg | None = None
        self.cycle_us: deque[float] = deque(maxlen=1000)
        self.gizmos: list[Any] = []
        self._seq = 0

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
        if self.q is None or self.verdict is None:
            return None
        return self.frame()

    def frame(self) -> DisplayFrame:
        assert self.q is not None and self.verdict is not None
        v = self.verdict
        humans, ends, radius, verified = (
            [],
            np.zeros((0, 0, 2, 3)),
            np.zeros((0, 0)),
            v.mode != "failsafe",
        )
        if self.occ is not None:
            for h in self.occ.humans:
                models = {name: caps.arrays() for name, caps in h.models.items()}
                y = np.asarray(h.joints_m).reshape(-1, 3)
                humans.append(HumanDisplay(h.id, y, _BONES, models))
            if self.occ.robot is not None:
                r = self.occ.robot
                e, rad = r.capsules.arrays()
                L = len(r.link_names)
                ends, radius = e.reshape(r.n_intervals, L, 2, 3), rad.reshape(r.n_intervals, L)
                verified = r.verified
        cu = np.array(self.cycle_us)
        ages = {k: 1e3 * a for k, a in v.skeleton_age_s.items()}
        status = {
            "mode": v.mode,
            "safety_mode": v.safety_mode,
            "min_distance_m": v.min_distance_m,
            "cycle_p50_us": float(np.median(cu)),
            "cycle_p99_us": float(np.percentile(cu, 99)),
            "skeleton_age_ms": ages,
            "dropped": dict(v.dropped),
            "models": dict(v.results),
            "faults": list(v.faults),
        }
        return DisplayFrame(
            t_s=v.stamp_s,
            q=self.q,
            humans=humans,
            robot_ends=ends,
            robot_radius=radius,
            verified=verified,
            status=status,
            boxes=boxes_of(self.scenario),
        )

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
        self.sub_ack.drain()
        msg = ParamsMsg(
            seq=self.pub_params.next_seq(),
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
        raise ScenarioError(f"the worker did not answer within {self.ack_timeout_s} s")

    def select(self, name: str) -> None:
        sc = load_scenario(name, self.folder)
        self.send(sc.model_dump(mode="json"))
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
        if self.dash.panels is not None:
            self.dash.panels.set_scenarios(list(scenario_names(self.folder)), self.scenario.name)
            self.dash.panels.set_params(self.editable())
        self.add_gizmos()

    def add_gizmos(self) -> None:
        """Drag handles for environment boxes and people's start positions."""
        server = self.dash.server
        if server is None:
            return
        for g in self.gizmos:
            g.remove()
        self.gizmos = []
        for i, b in enumerate(self.scenario.environment):
            g = server.scene.add_transform_controls(
                f"/edit/box_{i}", scale=0.3, position=b.center_m, disable_rotations=True
            )
            g.on_drag_end(self._on_box_drag(i, g))
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
            g.on_drag_end(self._on_human_drag(i, g))
            self.gizmos.append(g)

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
