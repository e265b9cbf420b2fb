"""Poses from a scenario's numbers: a position and roll-pitch-yaw to a homogeneous transform,
and the scenario's environment boxes as arrays.

Its own module, numpy only: the replayer, the display and the CLI need it without importing
the cell's shield and kernels (the replayer's start took 1.4 s, 1.2 s of it for this function's
old home, :mod:`sara_app.cell.build`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np


def pose_from_xyz_rpy(
    xyz: tuple[float, float, float], rpy: tuple[float, float, float]
) -> np.ndarray:
    """``T_world_frame (4, 4)`` from a position (m) and roll-pitch-yaw (rad, fixed axes x, y,
    z: ``R = Rz(yaw) Ry(pitch) Rx(roll)``)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    T = np.eye(4)
    T[:3, :3] = np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )
    T[:3, 3] = xyz
    return T


def box_arrays(boxes: Sequence[Any]) -> tuple[np.ndarray, np.ndarray]:
    """A scenario's ``environment`` (items with ``center_m``, ``rpy_rad``, ``size_m``) as
    ``T_world_box (B, 4, 4)`` and ``half_extents_m (B, 3)``."""
    if not boxes:
        return np.zeros((0, 4, 4)), np.zeros((0, 3))
    T = np.stack([pose_from_xyz_rpy(b.center_m, b.rpy_rad) for b in boxes])
    return T, np.array([b.size_m for b in boxes], dtype=float) * 0.5
