"""Liu et al. 2022's simulation study (Sec. 4.1-4.3) for the project's robots.

A robot holds its home pose (a jerk-level tracking law as the nominal controller, the role of the
paper's JPC) while a scripted human walks in front of it, stops and leaves. Each cycle the safety
filter (:class:`JssaController` or :class:`SsaController`) modifies the nominal jerk and the
robot integrates eq. 1. Outputs: the traces of minimum distance, relative velocity and
acceleration at the critical pair, critical links and filter activity (:func:`run_episode`,
:func:`plot_trace`), the sensitivity table over ``lambda_1, lambda_2`` in the format of Liu et al.
2022 Table 1 (:func:`sensitivity_table`) and JSSA versus SSA (:func:`compare_ssa`).

Reusable: a :class:`Scenario` is a robot, a home pose, a human function ``t -> HumanSample``
(capsules, end velocities and accelerations; the filter sees only positions and velocities) and
optional static obstacle capsules; any filter with the ``step`` API of :class:`JssaController`
runs in :func:`run_episode`.

The human is a rigid standing body (the 14 capsules of the ``full`` skeleton, radii = half the
thickness of the ``schepp2022_table1`` parameter set) translating in the XY plane, as the paper's
mouse-driven human does.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from sara_app.geometry.shapes import capsule_distances
from sara_app.human.scripted import PELVIS_Z_M
from sara_app.robot.model import RobotModel, load_robot
from sara_app.safety.jssa import JssaController, JssaParams, integrate
from sara_app.safety.ssa import SsaController


class HumanSample(NamedTuple):
    """Human capsules at one time: ends ``(M, 2, 3)``, radii ``(M,)``, end velocities and
    accelerations ``(M, 2, 3)`` (world frame, m, m/s, m/s^2)."""

    ends: np.ndarray
    radius: np.ndarray
    vel: np.ndarray
    acc: np.ndarray


HumanFn = Callable[[float], HumanSample]

# The standing body of the scripted motions (sara_app.human.scripted), arms held forward as when
# reaching towards a workbench: wrist targets relative to the pelvis (x forward, y left, z up).
_WRISTS_M = {"l": (0.42, 0.20, 0.32), "r": (0.38, -0.20, 0.20)}


def _human_geometry() -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
    """Body-part capsule ends relative to the pelvis ``(P, 2, 3)`` (facing +x), radii ``(P,)``
    (half the thickness of ``schepp2022_table1``) and part names, of the ``full`` skeleton."""
    from sara_app.human.params import load_param_set, to_reach_params
    from sara_app.human.scripted import aim_arm, joints, standing
    from sara_app.human.skeleton import skeleton

    sk = skeleton("full")
    pose = standing((0.0, 0.0), 0.0)
    for side, target in _WRISTS_M.items():
        pose = aim_arm(pose, side, pose.pelvis + np.array(target))
    y = joints(pose) - pose.pelvis
    radius = to_reach_params(load_param_set("schepp2022_table1"), "full").half_thickness_m
    return y[sk.part_joints], np.asarray(radius, dtype=float), sk.parts


_BODY_ENDS, _BODY_RADIUS, BODY_PARTS = _human_geometry()


def rigid_human(
    pelvis_xy: np.ndarray, yaw: float, vel_xy: np.ndarray, acc_xy: np.ndarray
) -> HumanSample:
    """The template body at ``pelvis_xy`` facing ``yaw`` (rad about z), translating with
    ``vel_xy``, ``acc_xy`` ``(2,)`` (no rotation, so every point shares them)."""
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    pelvis = np.array([pelvis_xy[0], pelvis_xy[1], PELVIS_Z_M])
    ends = _BODY_ENDS @ R.T + pelvis
    m = ends.shape[0]
    vel = np.broadcast_to(np.array([vel_xy[0], vel_xy[1], 0.0]), (m, 2, 3)).copy()
    acc = np.broadcast_to(np.array([acc_xy[0], acc_xy[1], 0.0]), (m, 2, 3)).copy()
    return HumanSample(ends, _BODY_RADIUS.copy(), vel, acc)


def seed_walk(
    x_far: float = 2.6, x_near: float = 1.2, y: float = 0.0, t0: float = 0.5, T: float = 5.0
) -> HumanFn:
    """The paper's Fig. 5 script: the human faces the robot (at the origin, looking along -x),
    walks from ``x_far`` to ``x_near``, decelerates, turns back and leaves; a raised-cosine
    profile ``x(t) = x_far - (x_far - x_near) (1 - cos(2 pi (t - t0) / T)) / 2`` on
    ``[t0, t0 + T]`` (peak speed ``pi (x_far - x_near) / T``)."""
    amp = x_far - x_near
    w = 2.0 * np.pi / T

    def fn(t: float) -> HumanSample:
        tau = min(max(t - t0, 0.0), T)
        inside = 0.0 < t - t0 < T
        x = x_far - amp * 0.5 * (1.0 - np.cos(w * tau))
        v = -amp * 0.5 * w * np.sin(w * tau) if inside else 0.0
        a = -amp * 0.5 * w * w * np.cos(w * tau) if inside else 0.0
        return rigid_human(np.array([x, y]), np.pi, np.array([v, 0.0]), np.array([a, 0.0]))

    return fn


PANDA_HOME = np.array([0.0, 0.2, 0.0, -1.6, 0.0, 1.8, 0.785])  # hand 0.62 m ahead, 1.21 m high
TABLE_HEIGHT_M = 0.75


@dataclass
class Scenario:
    """Inputs of one study run. Obstacles: static capsules ``(K, 2, 3)``, ``(K,)`` or None."""

    robot: RobotModel
    q_home: np.ndarray
    human: HumanFn
    duration_s: float = 7.0
    dt_s: float = 0.008
    obstacle_ends: np.ndarray | None = None
    obstacle_radius: np.ndarray | None = None
    home_omega_per_s: float = 4.0


def panda_on_table(robot: RobotModel | None = None) -> RobotModel:
    """The Panda on a 0.75 m table at the origin (the study's robot)."""
    if robot is not None:
        return robot
    T = np.eye(4)
    T[2, 3] = TABLE_HEIGHT_M
    return load_robot("panda", T_world_base=T)


def seed_scenario(robot: RobotModel | None = None, **walk: float) -> Scenario:
    """The Fig. 5 study: Panda on a table at home, the :func:`seed_walk` human."""
    return Scenario(panda_on_table(robot), PANDA_HOME.copy(), seed_walk(**walk))


def hold_home_jerk(
    q: np.ndarray, q_dot: np.ndarray, q_ddot: np.ndarray, q_home: np.ndarray, omega: float
) -> np.ndarray:
    """Nominal jerk that brings the robot back to ``q_home``: the triple-pole law
    ``u = -(w^3 e + 3 w^2 q' + 3 w q'')`` (the filter clips it to the jerk bounds)."""
    return -(omega**3 * (q - q_home) + 3.0 * omega**2 * q_dot + 3.0 * omega * q_ddot)


@dataclass
class Trace:
    """Per-cycle records of an episode, arrays of length ``N`` (``jerk``, ``q`` ``(N, n)``)."""

    t: np.ndarray
    distance_m: np.ndarray  # true minimum distance moving links - human/obstacles
    phi: np.ndarray
    rel_speed: np.ndarray  # |relative velocity| at the critical pair
    rel_acc: np.ndarray  # |relative acceleration| (robot model minus true human)
    link: np.ndarray
    other: np.ndarray
    active: np.ndarray
    fallback: np.ndarray
    saturated: np.ndarray  # some joint's jerk at its bound
    jerk: np.ndarray
    q: np.ndarray
    q_ddot: np.ndarray
    jerk_hi: np.ndarray


def run_episode(scenario: Scenario, filt: JssaController) -> Trace:
    """Closed loop: nominal hold-home jerk, filter, eq. 1; returns the :class:`Trace`."""
    sc = scenario
    robot = filt.robot
    n = robot.n_dof
    moving = filt.moving_links
    N = int(round(sc.duration_s / sc.dt_s))
    q, qd, qdd = sc.q_home.astype(float).copy(), np.zeros(n), np.zeros(n)
    rec: dict[str, list] = {k: [] for k in Trace.__dataclass_fields__ if k != "jerk_hi"}
    for k in range(N):
        t = k * sc.dt_s
        h = sc.human(t)
        u_nom = hold_home_jerk(q, qd, qdd, sc.q_home, sc.home_omega_per_s)
        res = filt.step(
            q, qd, qdd, u_nom, h.ends, h.radius, h.vel, sc.dt_s, sc.obstacle_ends,
            sc.obstacle_radius,
        )  # fmt: skip
        ends, radius = robot.link_capsules(q)
        o_ends, o_r = h.ends, h.radius
        if sc.obstacle_ends is not None and sc.obstacle_radius is not None:
            o_ends = np.concatenate([o_ends, sc.obstacle_ends])
            o_r = np.concatenate([o_r, sc.obstacle_radius])
        d_true = float(capsule_distances(ends[moving], radius[moving], o_ends, o_r).min())
        h_acc = h.acc[res.other_index].mean(axis=0) if 0 <= res.other_index < len(h.acc) else 0
        rec["t"].append(t)
        rec["distance_m"].append(d_true)
        rec["phi"].append(res.phi)
        rec["rel_speed"].append(float(np.linalg.norm(res.rel_vel)))
        rec["rel_acc"].append(float(np.linalg.norm(res.rel_acc - h_acc)))
        rec["link"].append(res.link_index)
        rec["other"].append(res.other_index)
        rec["active"].append(res.active)
        rec["fallback"].append(res.fallback)
        rec["saturated"].append(bool(np.any(np.abs(res.jerk) >= filt.jerk_hi * (1 - 1e-9))))
        rec["jerk"].append(res.jerk.copy())
        rec["q"].append(q.copy())
        rec["q_ddot"].append(qdd.copy())
        q, qd, qdd = integrate(q, qd, qdd, res.jerk, sc.dt_s)
    arrays = {k: np.array(v) for k, v in rec.items()}
    return Trace(**arrays, jerk_hi=filt.jerk_hi.copy())


class Summary(NamedTuple):
    """Liu et al. 2022 Table 1 entry plus the counts the comparison needs."""

    min_distance_m: float
    first_trigger_s: float
    last_trigger_s: float
    duration_s: float
    mean_rel_speed: float
    mean_rel_acc: float
    saturated_share: float
    fallbacks: int
    max_jerk_ratio: float
    mean_robot_acc: float


def summarize(tr: Trace) -> Summary:
    """Table 1 quantities of a trace (times in s; NaN trigger times when never active)."""
    dt = float(tr.t[1] - tr.t[0]) if len(tr.t) > 1 else 0.0
    act = np.flatnonzero(tr.active)
    first = float(tr.t[act[0]]) if act.size else float("nan")
    last = float(tr.t[act[-1]]) if act.size else float("nan")
    return Summary(
        min_distance_m=float(tr.distance_m.min()),
        first_trigger_s=first,
        last_trigger_s=last,
        duration_s=float(act.size * dt),
        mean_rel_speed=float(tr.rel_speed.mean()),
        mean_rel_acc=float(tr.rel_acc.mean()),
        saturated_share=float(tr.saturated.mean()),
        fallbacks=int(tr.fallback.sum()),
        max_jerk_ratio=float(np.max(np.abs(tr.jerk) / tr.jerk_hi)),
        mean_robot_acc=float(np.linalg.norm(tr.q_ddot, axis=1).mean()),
    )


def sensitivity_table(
    scenario: Scenario, values: tuple[float, ...] = (6.0, 7.0, 8.0), base: JssaParams | None = None
) -> dict[tuple[float, float], Summary]:
    """Summaries for every ``(lambda_1, lambda_2)`` in ``values x values`` (Liu et al. 2022 Sec.
    4.2)."""
    base = base or JssaParams()
    out = {}
    for l2 in values:
        for l1 in values:
            params = base.model_copy(update={"lambda_1": l1, "lambda_2": l2})
            out[(l1, l2)] = summarize(run_episode(scenario, JssaController(scenario.robot, params)))
    return out


def format_table(table: dict[tuple[float, float], Summary]) -> str:
    """Liu et al. 2022 Table 1 layout: rows lambda_2, columns lambda_1, entries (min distance; first
    trigger; last trigger; duration; mean critical velocity; mean critical acceleration)."""
    l1s = sorted({k[0] for k in table})
    l2s = sorted({k[1] for k in table})
    head = "lambda_2 \\ lambda_1 | " + " | ".join(f"{v:g}".center(46) for v in l1s)
    lines = [head, "-" * len(head)]
    for l2 in l2s:
        cells = []
        for l1 in l1s:
            s = table[(l1, l2)]
            cells.append(
                f"({s.min_distance_m:.3f}; {s.first_trigger_s:.3f}; {s.last_trigger_s:.3f}; "
                f"{s.duration_s:.3f}; {s.mean_rel_speed:.3f}; {s.mean_rel_acc:.3f})"
            )
        lines.append(f"{l2:<20g}| " + " | ".join(cells))
    lines.append(
        "entries: (minimum distance m; first trigger s; last trigger s; active duration s; "
        "mean critical velocity m/s; mean critical acceleration m/s^2)"
    )
    return "\n".join(lines)


def compare_ssa(
    scenario: Scenario, jssa: JssaParams | None = None, ssa_lambda_1: float = 3.0
) -> dict[str, tuple[Summary, Trace]]:
    """JSSA (default lambda_1 = 3, lambda_2 = 1) versus SSA (lambda_1 = 3), seed Sec. 4.3."""
    jssa = jssa or JssaParams()
    ssa = jssa.model_copy(update={"lambda_1": ssa_lambda_1, "lambda_2": 0.0, "mode": "single"})
    out = {}
    for name, filt in (
        ("JSSA", JssaController(scenario.robot, jssa)),
        ("SSA", SsaController(scenario.robot, ssa)),
    ):
        tr = run_episode(scenario, filt)
        out[name] = (summarize(tr), tr)
    return out


def format_comparison(res: dict[str, tuple[Summary, Trace]]) -> str:
    lines = [
        f"{'filter':6s} {'min d m':>8s} {'first s':>8s} {'last s':>8s} {'active s':>9s} "
        f"{'jerk sat %':>10s} {'fallbacks':>9s} {'max|u|/u_max':>12s} {'mean|qdd|':>10s}"
    ]
    for name, (s, _) in res.items():
        lines.append(
            f"{name:6s} {s.min_distance_m:8.3f} {s.first_trigger_s:8.3f} {s.last_trigger_s:8.3f} "
            f"{s.duration_s:9.3f} {100 * s.saturated_share:10.1f} {s.fallbacks:9d} "
            f"{s.max_jerk_ratio:12.3f} {s.mean_robot_acc:10.3f}"
        )
    return "\n".join(lines)


def format_trace(tr: Trace, every_s: float = 0.25) -> str:
    """The profile as text, one line per ``every_s``: t, distance, |v_rel|, |a_rel|, critical
    robot link / human part, active."""
    step = max(1, int(round(every_s / float(tr.t[1] - tr.t[0])))) if len(tr.t) > 1 else 1
    lines = [f"{'t s':>6s} {'d m':>7s} {'|v| m/s':>8s} {'|a| m/s2':>9s} link part  active"]
    for k in range(0, len(tr.t), step):
        part = BODY_PARTS[tr.other[k]] if 0 <= tr.other[k] < len(BODY_PARTS) else "-"
        lines.append(
            f"{tr.t[k]:6.2f} {tr.distance_m[k]:7.3f} {tr.rel_speed[k]:8.3f} {tr.rel_acc[k]:9.3f} "
            f"{tr.link[k]:4d} {part:12s} {'x' if tr.active[k] else ''}"
            f"{' FALLBACK' if tr.fallback[k] else ''}"
        )
    return "\n".join(lines)


def plot_trace(tr: Trace, path: str, title: str, d_min_m: float) -> None:
    """Liu et al. 2022 Fig. 6 style PNG: distance, relative velocity, relative acceleration,
    critical links, activity."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(5, 1, figsize=(8, 10), sharex=True)
    ax[0].plot(tr.t, tr.distance_m, label="min distance")
    ax[0].axhline(d_min_m, color="r", ls="--", label="d_min")
    ax[0].set_ylabel("m")
    ax[0].legend()
    ax[1].plot(tr.t, tr.rel_speed)
    ax[1].set_ylabel("|v_rel| m/s")
    ax[2].plot(tr.t, tr.rel_acc)
    ax[2].set_ylabel("|a_rel| m/s^2")
    ax[3].step(tr.t, tr.link, where="post", label="robot link")
    ax[3].step(tr.t, tr.other, where="post", label="human part")
    ax[3].set_ylabel("critical id")
    ax[3].legend()
    ax[4].step(tr.t, tr.active.astype(int), where="post", label="active")
    ax[4].step(tr.t, tr.fallback.astype(int), where="post", label="fallback")
    ax[4].set_ylabel("JSSA")
    ax[4].set_xlabel("t s")
    ax[4].legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
