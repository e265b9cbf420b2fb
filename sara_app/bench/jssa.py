"""``sara-app bench`` rows: one JSSA controller step."""

from __future__ import annotations

import numpy as np

from sara_app.safety.jssa import JssaController, JssaParams


def _bench_setup(mode: str) -> tuple[JssaController, tuple]:
    from sara_app.robot.model import load_robot
    from sara_app.studies.jssa_study import PANDA_HOME, TABLE_HEIGHT_M, rigid_human

    T = np.eye(4)
    T[2, 3] = TABLE_HEIGHT_M
    robot = load_robot("panda", T_world_base=T)
    ctrl = JssaController(robot, JssaParams(lambda_1=3.0, lambda_2=1.0, mode=mode))  # type: ignore[arg-type]
    h = rigid_human(np.array([1.3, 0.1]), np.pi, np.array([-0.8, 0.0]), np.zeros(2))
    rng = np.random.default_rng(0)
    q_dot, q_ddot = rng.normal(0, 0.3, robot.n_dof), rng.normal(0, 1.0, robot.n_dof)
    u0 = rng.normal(0, 100.0, robot.n_dof)
    return ctrl, (PANDA_HOME, q_dot, q_ddot, u0, h.ends, h.radius, h.vel, 0.008)


def bench_rows(n: int = 2000) -> list[tuple[str, float, float, str]]:
    """One JSSA cycle, Panda + one full-body human (14 capsules), single and multi mode."""
    from functools import partial

    from sara_app.bench import timeit_us

    rows = []
    for mode in ("single", "multi"):
        ctrl, args = _bench_setup(mode)
        res = ctrl.step(*args)
        med, p99 = timeit_us(partial(ctrl.step, *args), n)
        note = f"{res.n_constraints} constraint(s), active={res.active}; target p99 1000 us"
        rows.append((f"JSSA cycle ({mode}), Panda + 14 capsules", med, p99, note))
    return rows
