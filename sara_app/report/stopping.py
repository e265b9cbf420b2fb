"""The robot's stopping time and distance at its limits, beside ISO 13855's separation distance.

For each waypoint of the task, every joint starts at its velocity limit (both signs tried) and
the failsafe's joint stop (:func:`~sara_app.robot.failsafe.plan_joint_stop`, the straight-line
stop at the acceleration and jerk limits) brings it to rest. The stopping distance is the
longest path any capsule end point of the robot travels during the stop (sampled densely; the
path between samples is a chord, so the value is a lower bound of the true path length by at
most the sampling error, which the sample count keeps below 1 mm at these speeds).

ISO 13855: ``S = K T + C`` with ``T`` the whole response time (sensor delay + one control cycle
+ stopping time), ``K = 2000 mm/s``, and where that gives more than 500 mm, ``K = 1600 mm/s``
(not below 500 mm); ``C = 850 mm``, the intrusion allowance for a detection capability above
40 mm (reach of an arm), which a skeleton tracker has.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sara_app.robot.failsafe import plan_joint_stop
from sara_app.robot.model import JointLimits, RobotModel

K_FAST_M_S = 2.0
K_SLOW_M_S = 1.6
SWITCH_M = 0.5
C_M = 0.85
SAMPLES = 200


def iso13855_separation_m(response_time_s: float, c_m: float = C_M) -> float:
    """``S = K T + C`` (ISO 13855): K = 2 m/s, or 1.6 m/s (not below 0.5 m) where that is
    over 0.5 m."""
    s = K_FAST_M_S * response_time_s + c_m
    return s if s <= SWITCH_M else max(K_SLOW_M_S * response_time_s + c_m, SWITCH_M)


@dataclass(frozen=True)
class StopRow:
    """One waypoint's worst stop from full speed: ``stop_time_s``, ``stop_distance_m`` (the
    longest capsule end point path), ``response_time_s`` (delay + cycle + stop) and the ISO
    13855 separation ``iso_separation_m`` for it."""

    waypoint: int
    stop_time_s: float
    stop_distance_m: float
    response_time_s: float
    iso_separation_m: float


def stop_rows(
    robot: RobotModel,
    limits: JointLimits,
    waypoints_rad: np.ndarray,
    delay_s: float,
    cycle_s: float,
) -> list[StopRow]:
    """:class:`StopRow` per waypoint ``(W, n)``."""
    rows = []
    for w, q in enumerate(np.asarray(waypoints_rad, dtype=float)):
        t_stop, d_stop = 0.0, 0.0
        for sign in (1.0, -1.0):
            prof = plan_joint_stop(q, sign * limits.v_max, np.zeros_like(q), limits)
            t = np.linspace(0.0, prof.duration_s, SAMPLES)
            qs, _, _ = prof.sample(t)
            ends = robot.link_capsules_batch(qs)  # (S, L, 2, 3)
            path = np.linalg.norm(np.diff(ends, axis=0), axis=-1).sum(axis=0)  # (L, 2)
            t_stop = max(t_stop, prof.duration_s)
            d_stop = max(d_stop, float(path.max()))
        response = delay_s + cycle_s + t_stop
        rows.append(StopRow(w, t_stop, d_stop, response, iso13855_separation_m(response)))
    return rows
