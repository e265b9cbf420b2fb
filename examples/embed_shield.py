"""The verification core in your own control loop: no Zenoh, no worker process.

Your loop owns the clock, the robot driver and the tracker. Every cycle it gives the shield the
people it measured (joints, velocities with an error bound, the measurement's time stamp) and
the robot state it measured; the shield verifies the next step with its stop and returns the
command to send: the intended step when verified (slowed down when only a slower step
verifies), else the next step of the last verified stop.

Here the tracker is a scripted person walking toward the robot and the robot is ideal (it
reaches each command exactly). Replace ``measure_person`` and ``send_to_robot`` with yours.

    python examples/embed_shield.py --scenario standing_beside_path --cycles 2500
"""

from __future__ import annotations

import argparse
import math
from collections import Counter

import numpy as np

from sara_app.cell.build import build_cell
from sara_app.human.scripted import joints, standing
from sara_app.robot.trajectory import JointState
from sara_app.safety.shield import HumanState
from sara_app.scenario import load_scenario

WALK_MPS = 0.5


def measure_person(t_s: float) -> HumanState:
    """Your tracker: a person walking from x = 2.2 m toward the robot at 0.5 m/s, stopping at
    x = 0.9 m. Joints ``(15, 3)`` m, velocities ``(15, 3)`` m/s, their error bound ``(15,)``."""
    x = max(2.2 - WALK_MPS * t_s, 0.9)
    y = joints(standing((x, -0.3), math.pi))
    v = np.zeros_like(y)
    if x > 0.9:
        v[:, 0] = -WALK_MPS
    return HumanState("worker", y, v, np.full(len(y), 0.05), stamp_s=t_s)


def send_to_robot(command: JointState) -> JointState:
    """Your driver: send the set point, return the measured state (here: reached exactly)."""
    return command


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="standing_beside_path")
    ap.add_argument("--cycles", type=int, default=2500)
    args = ap.parse_args()
    cell = build_cell(load_scenario(args.scenario))
    shield, dt = cell.shield, cell.scenario.shield.dt_s
    measured: JointState | None = None
    modes: Counter[str] = Counter()
    closest, task, slowed = math.inf, 0, 0
    for k in range(args.cycles):
        t = k * dt
        result = shield.cycle(t, [measure_person(t)], measured)
        measured = send_to_robot(result.command)
        modes[result.mode] += 1
        slowed += result.mode == "intended" and result.speed_scale < 1.0
        if result.min_distance_m is not None:
            closest = min(closest, result.min_distance_m)
        if shield.task_done:  # back and forth along the task's waypoints
            task = cell.next_pass(task, loop=True) or 0
            shield.follower.replan(cell.passes[task])
    share = ", ".join(f"{m} {100 * n / args.cycles:.0f} %" for m, n in sorted(modes.items()))
    slow = 100 * slowed / args.cycles
    print(f"{args.cycles} cycles of {dt * 1e3:g} ms: {share} (slowed {slow:.0f} %); closest "
          f"{closest:.3f} m")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
