"""The one place that chooses a safety mode: every mode is built here from its settings and runs
behind the :class:`~sara_app.safety.shield.Shield` interface."""

from __future__ import annotations

import numpy as np

from sara_app.human.reach import HumanReach
from sara_app.robot.model import RobotModel
from sara_app.robot.trajectory import PathFollower
from sara_app.safety.settings import ShieldSettings
from sara_app.safety.shield import Shield


def build_safety(
    settings: ShieldSettings,
    robot: RobotModel,
    follower: PathFollower,
    reach: HumanReach,
    boxes: tuple[np.ndarray, np.ndarray],
) -> Shield:
    """``settings.mode`` around the follower: ``ssm`` (:class:`Shield`), ``pfl``
    (:class:`~sara_app.safety.pfl_shield.PflShield`) or ``jssa``
    (:class:`~sara_app.safety.jssa_mode.JssaMode`). ``boxes``: the environment as
    ``T_world_box (B, 4, 4)`` and ``half_extents_m (B, 3)`` (SSM does not use them)."""
    if settings.mode == "pfl":
        from sara_app.safety.pfl_shield import PflShield  # compiles the PFL kernels: on use

        return PflShield(robot, follower, reach, settings, settings.pfl, boxes)
    if settings.mode == "jssa":
        from sara_app.safety.jssa_mode import JssaMode

        return JssaMode(robot, follower, reach, settings, settings.jssa, boxes)
    return Shield(robot, follower, reach, settings)
