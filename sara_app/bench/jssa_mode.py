"""``sara-app bench`` rows: one JSSA mode cycle of the cell."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from sara_app.human.reach import HumanReach
from sara_app.safety.jssa_mode import JssaMode
from sara_app.safety.settings import JssaSettings, ShieldSettings
from sara_app.safety.shield import HumanState


def _bench_mode(constraints: str = "single") -> tuple[JssaMode, list[HumanState]]:
    from sara_app.human.params import load_param_set, to_reach_params
    from sara_app.human.scripted import joints, standing
    from sara_app.robot.model import load_robot
    from sara_app.robot.trajectory import PathFollower

    robot = load_robot("panda")
    reach = HumanReach(to_reach_params(load_param_set("schepp2022_table1"), "full"))
    wps = np.array([[-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8], [1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8]])
    follower = PathFollower(wps, robot.limits, blend_distance=0.1)
    spec = JssaSettings(constraints=constraints)  # type: ignore[arg-type]
    mode = JssaMode(robot, follower, reach, ShieldSettings(), spec)
    for k in range(150):  # moving at speed
        mode.cycle(k * mode.settings.dt_s, [])
    y = joints(standing((1.85, 0.0), math.pi))
    human = HumanState("p", y, np.tile([-0.5, 0.0, 0.0], (len(y), 1)), np.full(len(y), 0.1), 0.6)
    return mode, [human]


def _bench_cycle(mode: JssaMode, humans: list[HumanState]) -> Callable[[], object]:
    """The same cycle every call: the follower and robot state are restored first (a few us)."""
    f0, (q0, v0, a0) = mode.follower.copy(), (mode._q, mode._v, mode._a)

    def one() -> object:
        mode.follower = f0.copy()
        mode._q, mode._v, mode._a = q0, v0, a0
        return mode.cycle(0.61, humans, want_distance=False)

    return one


def bench_rows(n: int = 2000) -> list[tuple[str, float, float, str]]:
    """One :class:`JssaMode` cycle: Panda moving along its task at full speed, one full-body
    person about 1 m away walking toward it (14 capsules); one constraint (the paper's) and one
    per capsule pair (``multi``)."""
    from sara_app.bench import timeit_us

    rows = []
    for constraints in ("single", "multi"):
        mode, humans = _bench_mode(constraints)
        d = mode.min_distance(mode.robot_state.q, [humans[0].y])
        one = _bench_cycle(mode, humans)
        res = one()
        med, p99 = timeit_us(one, n)
        jr = res.jssa  # type: ignore[attr-defined]
        note = (
            f"distance {d:.2f} m, {jr.n_constraints} constraint(s), active={bool(jr.active)}; "
            "target p99 1000 us"
        )
        rows.append((f"JSSA mode cycle ({constraints}), Panda + 1 person", med, p99, note))
    return rows
