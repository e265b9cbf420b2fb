"""PFL costs for ``sara-app bench``: the PFL check alone (:func:`check_rows`: Panda, one
full-body person's R_VEL capsules, one table, K = 10) and one PFL shield cycle in the states of
:data:`BENCH_CASES` with the stages of a check (:func:`shield_rows`)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from sara_app.bench import timeit_us
from sara_app.errors import InputError, ScenarioError
from sara_app.robot.trajectory import PathFollower
from sara_app.safety.pfl import PflCheck
from sara_app.safety.pfl_shield import PflCycle, PflShield
from sara_app.safety.shield import CycleResult, Shield

Row = tuple[str, float, float, str]


def bench_rows(n: int = 2000) -> list[Row]:
    """:func:`check_rows` and :func:`shield_rows`."""
    return check_rows(n) + shield_rows(n)


def check_scene(K: int = 10) -> tuple[PflCheck, dict[str, np.ndarray]]:
    from sara_app.human.params import load_param_set, to_reach_params
    from sara_app.human.reach import HumanReach
    from sara_app.human.skeleton import skeleton
    from sara_app.robot.model import load_robot

    model = load_robot("panda")
    sk = skeleton("full")
    pfl = PflCheck(model, sk.parts, link_shapes={"panda_hand": "edge"})
    rng = np.random.default_rng(0)
    lim = model.limits
    t = np.linspace(0.0, 0.1, K + 1)
    q0 = np.array([0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8])
    qd = 0.3 * lim.v_max * rng.uniform(-1, 1, 7)
    q = q0 + t[:, None] * qd
    y = np.array(
        [[0.6, 0.0, 1.7], [0.6, 0.0, 1.5], [0.6, 0.0, 1.0], [0.6, 0.2, 1.45], [0.6, -0.2, 1.45]]
        + [[0.45, 0.25, 1.2], [0.45, -0.25, 1.2], [0.35, 0.2, 1.0], [0.35, -0.2, 1.0]]
        + [[0.6, 0.1, 0.95], [0.6, -0.1, 0.95], [0.6, 0.1, 0.5], [0.6, -0.1, 0.5]]
        + [[0.6, 0.1, 0.05], [0.6, -0.1, 0.05]]
    )
    reach = HumanReach(to_reach_params(load_param_set("schepp2022_table1"), "full"))
    occ = reach.vel(y[None], t[1:])
    h_ends = np.broadcast_to(occ.ends[0], (K, sk.n_parts, 2, 3)).copy()
    h_radius = np.broadcast_to(occ.radius[0], (K, sk.n_parts)).copy()
    T_box = np.eye(4)[None].copy()
    T_box[0, :3, 3] = [0.5, 0.0, 0.35]
    scene = {
        "q": q,
        "q_dot": np.broadcast_to(qd, q.shape).copy(),
        "qd_bound": np.broadcast_to(np.abs(qd), (K, 7)).copy(),
        "t": t,
        "h_ends": h_ends,
        "h_radius": h_radius,
        "T_world_box": T_box,
        "half_extents_m": np.array([[0.4, 0.6, 0.02]]),
    }
    return pfl, scene


def check_rows(n: int = 2000) -> list[Row]:
    """The PFL check alone: Panda, one full-body human (R_VEL), one table, 10 intervals."""
    pfl, sc = check_scene(10)
    q, qd, t = sc["q"], sc["q_dot"], sc["t"]
    human = (sc["h_ends"], sc["h_radius"], sc["T_world_box"], sc["half_extents_m"])
    r_ends, r_radius = pfl.occupancy.intervals(q, sc["qd_bound"], t)
    smp = pfl.motion.evaluate(q, qd)
    s = (smp.ends.copy(), smp.p1_dot.copy(), smp.omega.copy(), smp.energy_J.copy())
    rows = []
    for name, fn in (
        ("pfl: energies + twists (11 samples)", lambda: pfl.motion.evaluate(q, qd)),
        (
            "pfl: contact classification",
            lambda: pfl.classifier.classify(
                r_ends,
                r_radius,
                s[0],
                pfl._s_radius,
                s[1],
                s[2],
                pfl.velocity_error.eps_v(np.diff(t)),
                *human,
            ),  # fmt: skip
        ),
        (
            "pfl: check (given link states)",
            lambda: pfl.check(r_ends, r_radius, s[0], s[1], s[2], np.diff(t), *human, s[3]),
        ),
        (
            "pfl: full cycle incl. occupancy",
            lambda: pfl.check_trajectory(q, qd, sc["qd_bound"], t, *human),
        ),
    ):
        med, p99 = timeit_us(fn, n, warmup=max(10, n // 10))
        rows.append((name, med, p99, "Panda, 14 parts, 1 box, K=10"))
    far = (sc["h_ends"] + np.array([3.0, 0.0, 0.0]), *human[1:])
    med, p99 = timeit_us(
        lambda: pfl.check_trajectory(q, qd, sc["qd_bound"], t, *far), n, warmup=max(10, n // 10)
    )
    rows.append(("pfl: full cycle, human 3 m away", med, p99, "Panda, 14 parts, 1 box, K=10"))
    return rows


def bench_cell(
    mode: str, xys: list[tuple[float, float]]
) -> tuple[Shield, PathFollower, list[Any], float]:
    """The benchmarks' cell (Panda, a table, models acc/vel/pos) in safety mode ``mode`` with
    the robot at full speed after 0.16 s, and standing full-body people at ``xys`` facing the
    robot base."""
    from sara_app.cell.build import build_cell
    from sara_app.human.scripted import joints, standing
    from sara_app.safety.shield import HumanState
    from sara_app.scenario import parse_scenario

    q = [0.3, 0.0, -1.8, 0.0, 2.1, 0.8]
    sc = parse_scenario(
        {
            "name": "bench",
            "task": {"waypoints_rad": [[-1.2, *q], [1.2, *q]]},
            "environment": [
                {"name": "table", "center_m": [0.65, 0.0, 0.1], "size_m": [0.5, 1.6, 0.2]}
            ],
            "shield": {"mode": mode, "models": ["acc", "vel", "pos", "combined"]},
            "inputs": {"max_people": max(8, len(xys))},
            "human_params": "schepp2022_table1",  # the published timings' set
        }
    )
    shield = build_cell(sc).shield
    t = 0.0
    for _ in range(40):
        shield.cycle(t, [])
        t += shield.settings.dt_s
    people = []
    for i, xy in enumerate(xys):
        y = joints(standing(xy, math.atan2(-xy[1], -xy[0])))
        pid = "p" if len(xys) == 1 else f"p{i}"
        people.append(HumanState(pid, y, np.zeros_like(y), np.full(len(y), 0.05), t - 0.012))
    return shield, shield.follower.copy(), people, t


def shield_cell(xy: tuple[float, float]) -> tuple[PflShield, PathFollower, list[Any], float]:
    """:func:`bench_cell` in PFL with one person at ``xy``."""
    shield, template, people, t = bench_cell("pfl", [xy])
    if not isinstance(shield, PflShield):
        raise ScenarioError(f"the PFL benchmark cell built a {type(shield).__name__}")
    return shield, template, people, t


BENCH_CASES = {
    "clear": (1.0, -1.0),
    "slowed": (1.1, -0.4),
    "braking": (0.9, -0.4),
}
"""Person positions (m, world) for the benchmark, robot hand at about (0.34, -0.54): the first
check verifies / a failed check and a verified replan at a lower cap / both fail."""


def shield_rows(n: int = 2000) -> list[Row]:
    """One PFL shield cycle (plan, human sets, PFL check per model, replan, commit or brake):
    Panda at full speed, one standing full-body person, one table, in the three
    :data:`BENCH_CASES` (every cycle from the same state with no cap: the worst case, a
    failed check at full speed first), plus the slowed case in the steady state of a closed
    loop (the cap found by the previous cycle kept: one check); then the stages of the braking
    cycle: the first plan, the link states of one trajectory (inside the check when a contact
    is possible) and the checks with the replan (:mod:`sara_app.safety.pfl_cycle`)."""
    rows = []
    cases = [(case, xy, False) for case, xy in BENCH_CASES.items()]
    cases.append(("slowed, cap held", BENCH_CASES["slowed"], True))
    for case, xy, hold in cases:
        shield, template, people, t = shield_cell(xy)
        shield.cycle(t, people, want_distance=False)
        info = shield._res
        held = info.cap if hold and isinstance(info, PflCycle) else math.inf
        shield.follower = template.copy()

        def cycle(
            shield: PflShield = shield,
            template: PathFollower = template,
            people: list[Any] = people,
            t: float = t,
            held: float = held,
        ) -> CycleResult:
            shield.follower = template.copy()
            shield.cap, shield._calm = held, 0
            return shield.cycle(t, people, want_distance=False)

        out = cycle()
        info = shield._res
        d = shield.min_distance(template.state.q, [people[0].y])
        note = f"person {d:.2f} m from the robot; {out.mode}"
        if isinstance(info, PflCycle) and out.trajectory is not None:
            note += (
                f", {info.checks} check(s), {info.models_used} model(s) in the last, speed "
                f"scale {out.speed_scale:.2f}, K = {len(out.trajectory.times) - 1}; target p99 "
                "1 ms"
            )
        med, p99 = timeit_us(cycle, n, warmup=max(10, n // 10))
        rows.append((f"pfl shield cycle, {case}", med, p99, note))
        if case == "braking":
            braking = (shield, template, people, t)
    shield, template, people, t = braking
    # stages of one cycle (the braking case: two checks, every model evaluated)
    shield.follower = template.copy()
    traj, ends, radius = shield._plan(math.inf)
    hum = shield._human_arrays(people, [0], {"p": t - float(people[0].stamp_s)})
    if hum is None:
        raise InputError("the benchmark's person was not usable by the shield")
    K = len(traj.times) - 1
    sc = shield.scaling

    def checks() -> object:
        orders = (list(shield._orders[0]), list(shield._orders[1]))
        return shield.compiled.run(shield.follower, traj, ends, radius, hum,
                                   (math.inf, 0.0, sc.cut), (sc.max_replans, sc.model_budget(1)),
                                   orders)  # fmt: skip

    stages: list[tuple[str, Any]] = [
        ("  shielded trajectory + occupancy", lambda: shield._plan(math.inf)),
        ("  link energies, twists, energy and error bounds", lambda: shield._link_energies(traj)),
        ("  checks and replan (one compiled call)", checks),
    ]
    for name, fn in stages:
        med, p99 = timeit_us(fn, n, warmup=max(10, n // 10))
        rows.append((name, med, p99, f"braking case, K = {K}"))
    return rows
