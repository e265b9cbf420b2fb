"""``sara-app bench`` rows: inverse kinematics of a waypoint drag."""

from __future__ import annotations

import numpy as np

from sara_app.robot.ik import end_effector_frame, solve_ik


def bench_rows(n: int = 200) -> list[tuple[str, float, float, str]]:
    """A waypoint drag: the Panda's tool moved 5 cm from a random configuration (warm start at
    the old one), and an unreachable target (all restarts)."""
    from sara_app.bench import timeit_us
    from sara_app.robot.model import load_robot

    robot = load_robot("panda")
    frame = end_effector_frame(robot)
    rng = np.random.default_rng(0)
    lim = robot.limits
    cases = []
    for _ in range(32):
        q = rng.uniform(lim.q_min, lim.q_max)
        T = robot.frame_pose(q, frame)
        T[:3, 3] += rng.normal(size=3) * 0.05 / np.sqrt(3)
        cases.append((T, q))
    far = np.eye(4)
    far[:3, 3] = (3.0, 0.0, 0.5)
    q_mid = 0.5 * (lim.q_min + lim.q_max)
    i = [0]

    def drag() -> None:
        T, q = cases[i[0] % len(cases)]
        i[0] += 1
        solve_ik(robot, T, q)

    med, p99 = timeit_us(drag, max(n // 4, 10), warmup=3)
    rows = [("ik: waypoint drag 5 cm (Panda, pose)", med, p99, "warm start at the old waypoint")]
    med, p99 = timeit_us(lambda: solve_ik(robot, far, q_mid), max(n // 40, 3), warmup=1)
    rows.append(("ik: unreachable target (Panda)", med, p99, "17 starts, refused"))
    return rows
