"""Shield cycle costs for ``sara-app bench``: one SSM cycle of the Panda with one full-body person
near it, and its stages (shielded trajectory, robot occupancy, human sets + verification).

Set-up: the Panda of the shipped scenarios' pick-and-place (joint 1 sweeping from -1.2 to
1.2 rad), driven to cruise at joint 1's velocity limit (2.175 rad/s) so the failsafe is long; a
person standing 1.1 m from the base facing it, measured 10 ms ago, velocity 0 with a 0.05 m/s
error bound; default :class:`ShieldSettings` (dt 4 ms, intervals at most 20 ms, models POS, VEL,
ACC). The interval count ``K`` is one intended step plus ``ceil(stop duration / 20 ms)`` failsafe
intervals; the note of the first row reports ``K`` and the stop duration. Every timed call
restarts from the same follower state (a shallow copy), so the robot does not drift. The first
row is the cycle as the cell worker calls it (no measured state: the worker checks its robot's
tracking itself, at the measurement's time), with the separation the verdict reports.
"""

from __future__ import annotations

import math

import numpy as np

from sara_app.bench import timeit_us
from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.scripted import joints, standing
from sara_app.robot.model import load_robot
from sara_app.robot.shielded import shielded_trajectory
from sara_app.robot.trajectory import PathFollower
from sara_app.safety.settings import ShieldSettings
from sara_app.safety.shield import CycleResult, HumanState, Shield

Row = tuple[str, float, float, str]
WAYPOINTS_RAD = np.array(
    [[-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8], [1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8]]
)
PERSON_XY_M = (1.1, 0.3)


def _setup() -> tuple[Shield, PathFollower, list[HumanState], float]:
    robot = load_robot("panda")
    reach = HumanReach(to_reach_params(load_param_set("schepp2022_table1"), "full"))
    shield = Shield(robot, PathFollower(WAYPOINTS_RAD, robot.limits), reach, ShieldSettings())
    yaw = math.atan2(-PERSON_XY_M[1], -PERSON_XY_M[0])
    y = joints(standing(PERSON_XY_M, yaw))
    t = 0.0
    dt = shield.settings.dt_s
    for _ in range(100):  # person far away while the robot speeds up
        far = HumanState("p", y + [2.0, 0.0, 0.0], np.zeros_like(y), np.full(15, 0.05), t - 0.01)
        shield.cycle(t, [far], shield.follower.state, want_distance=False)
        t += dt
    human = HumanState("p", y, np.zeros_like(y), np.full(15, 0.05), t - 0.01)
    return shield, shield.follower.copy(), [human], t


def bench_rows(n: int = 2000) -> list[Row]:
    """Median and p99 (us) of one shield cycle and of its stages."""
    shield, base, humans, t = _setup()
    s = shield.settings
    h = humans[0]

    measured = base.state  # a measured robot state (computed outside the timed calls)

    def cycle(with_measured: bool = False) -> CycleResult:
        """The cycle as the cell worker calls it (its robot's tracking is checked against the
        measured state's own time, outside the shield: ``runtime.robot_link``), or with a
        measured state for the shield to track (the simulator's call)."""
        shield.follower = base.copy()
        return shield.cycle(t, humans, measured if with_measured else None)

    res = cycle()
    traj = shielded_trajectory(base, s.dt_s, max_interval_s=s.max_interval_s)
    K = len(traj.times) - 1
    ends, radius = shield.occupancy.intervals_of(traj)
    radius += shield.tracking_margin_m
    y, v, dv = h.y[None], h.v[None], h.dv[None]
    age = np.array([t - (h.stamp_s or 0.0)])
    verdict = "verified" if res.verified else "not verified"
    rows: list[Row] = []
    med, p99 = timeit_us(cycle, n)
    rows.append(
        (
            "shield cycle, Panda + 1 full-body human",
            med,
            p99,
            f"as the cell worker calls it; K = {K} intervals (1 step + stop "
            f"{traj.stop.duration_s:.3f} s in <= {s.max_interval_s * 1e3:.0f} ms), models "
            f"{'/'.join(s.models)}, {verdict}, separation for the verdict",
        )
    )
    idle = 0.002
    med, p99 = timeit_us(cycle, max(n // 4, 100), idle_s=idle)
    rows.append(("  the same, 2 ms idle before each", med, p99,
                 f"as in a live cell at {1 / idle:.0f} Hz: each cycle starts cold"))  # fmt: skip
    med, p99 = timeit_us(lambda: cycle(True), n)
    note = "the simulator's call (the command's position recomputed: a copied follower)"
    rows.append(("  with a measured state to track", med, p99, note))
    med, p99 = timeit_us(
        lambda: shielded_trajectory(base, s.dt_s, max_interval_s=s.max_interval_s), n
    )
    rows.append(("  shielded trajectory (step + failsafe)", med, p99, f"K = {K}"))
    med, p99 = timeit_us(lambda: shield.occupancy.intervals_of(traj), n)
    rows.append(("  robot occupancy", med, p99, f"{K} x {ends.shape[1]} link capsules"))
    med, p99 = timeit_us(lambda: shield.verifier.verify(y, v, dv, age, traj.times, ends, radius), n)
    rows.append(("  human sets + verification", med, p99, "all models until cleared"))
    return rows


def run(n: int = 2000) -> None:
    for name, med, p99, note in bench_rows(n):
        print(f"{name:44s} {med:10.1f} {p99:10.1f}  {note}")


if __name__ == "__main__":
    run()
