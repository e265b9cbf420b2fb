"""A cell built from a scenario: robot model, task passes, human parameters and the shield.

Shared by the simulator and the cell worker so both verify with exactly the same setup.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sara_app.cell.checksum import config_checksum
from sara_app.geometry.poses import box_arrays, pose_from_xyz_rpy
from sara_app.human.params import ParamSet, ReachParams, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.robot.model import JointLimits, RobotModel
from sara_app.robot.trajectory import PathFollower
from sara_app.safety.modes import build_safety
from sara_app.safety.shield import Shield
from sara_app.scenario import Scenario


def scaled_limits(limits: JointLimits, v: float, a: float, j: float) -> JointLimits:
    return JointLimits(
        limits.q_min,
        limits.q_max,
        limits.v_max * v,
        limits.a_max * a,
        limits.j_max * j,
        limits.tau_max,
    )


def environment_boxes(sc: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """The scenario's boxes as ``T_world_box (B, 4, 4)`` and ``half_extents_m (B, 3)``."""
    return box_arrays(sc.environment)


@dataclass
class Cell:
    """``passes``: the task's waypoint arrays ``(W, n)``, run one after the other (back and
    forth); ``param_set`` / ``params``: the human parameters (full skeleton)."""

    scenario: Scenario
    robot: RobotModel
    limits: JointLimits
    passes: list[np.ndarray]
    param_set: ParamSet
    params: ReachParams
    shield: Shield
    checksum: str
    """The configuration checksum (:func:`~sara_app.cell.checksum.config_checksum`): reported in the
    worker's status, printed in the evidence report."""

    def next_pass(self, index: int, loop: bool) -> int | None:
        """The pass after ``index``: the next one, or (``loop``) the first one that starts where
        the robot stands (passes alternate direction); None when the task is over."""
        n = len(self.passes)
        if index + 1 < n:
            return index + 1
        if not loop:
            return None
        # after an even number of passes the robot is back at the first waypoint
        return 0 if n % 2 == 0 else 1 % n


def build_cell(sc: Scenario) -> Cell:
    T = pose_from_xyz_rpy(sc.robot.base_xyz_m, sc.robot.base_rpy_rad)
    robot = sc.robot.load(T)
    lim = scaled_limits(robot.limits, sc.limits.velocity, sc.limits.acceleration, sc.limits.jerk)
    wps = np.asarray(sc.task.waypoints_rad, dtype=float)
    passes = [wps if i % 2 == 0 else wps[::-1] for i in range(sc.task.cycles)]
    follower = PathFollower(passes[0], lim, blend_distance=sc.task.blend_distance_rad)
    ps = sc.param_set()
    params = to_reach_params(ps, "full")
    shield = build_safety(sc.shield, robot, follower, HumanReach(params), environment_boxes(sc))
    return Cell(sc, robot, lim, passes, ps, params, shield, config_checksum(sc))
