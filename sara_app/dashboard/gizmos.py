"""Editing with drag handles in the 3D view: environment boxes, people's start positions and the
robot's task waypoints (the tool frame's pose; inverse kinematics from the old waypoint,
:mod:`sara_app.robot.ik`). A drag is applied when the handle is let go, through the cell view's
validated :meth:`send`; a refused edit shows its reason and puts the handles back."""

from __future__ import annotations

import copy
import logging
from typing import Any

import numpy as np

from sara_app.dashboard.access import acting
from sara_app.dashboard.capsules import rotation_to_wxyz
from sara_app.dashboard.viewer import Dashboard
from sara_app.errors import SaraError, ScenarioError
from sara_app.geometry.poses import pose_from_xyz_rpy
from sara_app.robot.ik import end_effector_frame, pose_from_wxyz, solve_ik
from sara_app.robot.model import RobotModel
from sara_app.scenario import Scenario

log = logging.getLogger("sara_app.dashboard")


def _on_release(gizmo: Any, callback: Any) -> None:
    """Call ``callback(event)`` when the user lets go of ``gizmo`` (drag phase "end")."""

    def handler(event: Any) -> None:
        if getattr(event, "phase", "end") == "end":
            with acting(event):  # the dragging browser's change
                callback(event)

    gizmo.on_update(handler)


class GizmoEditing:
    """Drag-handle editing of a :class:`~sara_app.dashboard.bridge.CellView` (a mixin: uses
    its ``scenario``, ``dash`` and ``send``)."""

    scenario: Scenario
    dash: Dashboard
    gizmos: list[Any]
    _robot_key: tuple[Any, ...] | None
    _robot_model: RobotModel | None

    def send(
        self, data: dict[str, Any], action: str = "scenario", confirm: bool = False
    ) -> Scenario:
        raise NotImplementedError

    def confirmed(self) -> bool:
        raise NotImplementedError

    # -- robot waypoints -----------------------------------------------------------------------

    def robot(self) -> RobotModel:
        """The scenario's robot at its base pose (reloaded when the robot or base changes)."""
        r = self.scenario.robot
        key = (r.name, tuple(r.base_xyz_m), tuple(r.base_rpy_rad))
        if self._robot_model is None or key != self._robot_key:
            T = pose_from_xyz_rpy(r.base_xyz_m, r.base_rpy_rad)
            self._robot_model = r.load(T, margin=False)
            self._robot_key = key
        return self._robot_model

    def waypoint_poses(self) -> np.ndarray:
        """World poses ``(W, 4, 4)`` of the tool frame at the task's waypoints."""
        robot = self.robot()
        frame = end_effector_frame(robot)
        wps = self.scenario.task.waypoints_rad
        return np.stack([robot.frame_pose(np.asarray(q, dtype=float), frame) for q in wps])

    def move_waypoint(self, i: int, wxyz: Any, position_m: Any) -> np.ndarray:
        """Solve waypoint ``i`` for the tool pose a drag left (``wxyz (4,)``, ``position_m
        (3,)``, world; warm start: the old waypoint) and send the edited scenario; the new joint
        positions. Raises :class:`ScenarioError` (nothing sent) when the pose is out of reach,
        :class:`InputError` when it is not a pose (a client may send NaN). One audited change
        (:mod:`sara_app.dashboard.access`), refused ones included."""

        def move() -> np.ndarray:
            T = pose_from_wxyz(np.asarray(wxyz, dtype=float), np.asarray(position_m, dtype=float))
            return self._move_waypoint(i, T)

        return self.dash.access.change(f"waypoint-{i}", move)

    def _move_waypoint(self, i: int, T_world_target: np.ndarray) -> np.ndarray:
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
        self.send(data, f"waypoint-{i}")
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
                self.move_waypoint(i, g.wxyz, g.position)

            self._report(f"waypoint {i}", apply)

        return cb

    def _report(self, what: str, fn: Any) -> None:
        panels = self.dash.panels
        try:
            fn()
            if panels is not None:
                panels.show_message(f"{what}: applied")
        except (SaraError, ValueError) as e:
            if panels is not None:
                panels.show_message(f"{what} refused: {e}", error=True)
            self.add_gizmos()  # back to the accepted positions

    def _on_box_drag(self, i: int, g: Any) -> Any:
        def cb(_event: Any) -> None:
            def apply() -> None:
                data = self.scenario.model_dump(mode="json")
                data["environment"][i]["center_m"] = [float(x) for x in g.position]
                self.send(data, f"box-{i}", self.confirmed())  # a moved box loosens

            self._report(f"box {i}", apply)

        return cb

    def _on_human_drag(self, i: int, g: Any) -> Any:
        def cb(_event: Any) -> None:
            def apply() -> None:
                data = copy.deepcopy(self.scenario.model_dump(mode="json"))
                data["humans"][i]["position_m"] = [float(g.position[0]), float(g.position[1])]
                self.send(data, f"person-{i}")

            self._report(f"person {i}", apply)

        return cb
