"""Closed-loop simulation of a scenario: simulated sensors, the shield, a robot that executes the
shield's commands exactly, and ground-truth collision checks.

Timeline of one step at time ``t``: each human's true pose at ``t`` is recorded; sensors whose
sample time has come publish the pose of an earlier simulation step ``t_m`` (the newest with
``t_m <= t - delay``) with bounded noise, stamped ``t_m + delay`` (so the stamp's meaning, "the
pose at stamp minus delay", is exact); the shield runs its cycle at ``t`` and the robot moves
along the committed (or braking) step to ``t + dt``.

Ground truth: a collision is a robot link capsule (fitted to the collision geometry, no margin)
overlapping a true body part (capsule with the parameter set's thickness) while the robot moves.
Contact with a robot at rest is allowed (SSM). Collisions are checked at every simulation step.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field

import numpy as np

from sara_app.cell import build_cell
from sara_app.human.motions import HumanMotion, make_motion, measured
from sara_app.human.velocity import VelocityEstimator
from sara_app.robot.model import RobotModel, load_robot
from sara_app.safety.shield import CycleResult, HumanState
from sara_app.safety.ssm import body_distance
from sara_app.scenario import Scenario

_MOVING_RAD_S = 1e-6


@dataclass
class _Sensor:
    rate_hz: float
    noise_m: float
    next_s: float
    estimator: VelocityEstimator
    state: HumanState


@dataclass
class SimMetrics:
    scenario: str
    duration_s: float
    cycles: int
    collisions_moving: int
    first_collision_s: float | None
    min_separation_m: float
    min_separation_moving_m: float
    failsafe_share: float
    fault_cycles: int
    time_to_goal_s: float | None
    cycle_us_p50: float
    cycle_us_p99: float
    modes: dict[str, int] = field(default_factory=dict)

    def lines(self) -> list[str]:
        ttg = f"{self.time_to_goal_s:.2f} s" if self.time_to_goal_s is not None else "not reached"
        return [
            f"scenario            {self.scenario}",
            f"simulated           {self.duration_s:.2f} s, {self.cycles} cycles",
            f"collisions moving   {self.collisions_moving}"
            + (f" (first at {self.first_collision_s:.3f} s)" if self.first_collision_s else ""),
            f"min separation      {self.min_separation_m:.3f} m "
            f"(while moving {self.min_separation_moving_m:.3f} m)",
            f"failsafe share      {100 * self.failsafe_share:.1f} % of cycles"
            f" (faults: {self.fault_cycles})",
            f"time to goal        {ttg}",
            f"shield cycle        p50 {self.cycle_us_p50:.0f} us, p99 {self.cycle_us_p99:.0f} us",
            "modes               " + ", ".join(f"{k} {v}" for k, v in sorted(self.modes.items())),
        ]


class Simulation:
    """One scenario in closed loop. ``step()`` advances one control cycle."""

    def __init__(self, sc: Scenario) -> None:
        self.scenario = sc
        cell = build_cell(sc)
        self.robot: RobotModel = cell.robot
        self.truth_robot = (
            cell.robot
            if sc.robot.margin_m == 0
            else load_robot(sc.robot.name, T_world_base=cell.robot.T_world_base)
        )
        self.cell = cell
        self.pass_index = 0
        ps = cell.param_set
        self.params = cell.params
        reach = cell.shield.reach
        self.shield = cell.shield
        s = sc.shield
        self.dt = s.dt_s
        self.rng = np.random.default_rng(sc.sim.seed)
        self.motions: list[HumanMotion] = [make_motion(h, self.params) for h in sc.humans]
        J = reach.skeleton.n_joints
        self.sensors = [
            _Sensor(
                h.sensor.rate_hz,
                h.sensor.noise_m,
                0.0,
                VelocityEstimator(J, ps.delta_y_m, self.params.a_max_mps2),
                HumanState.unmeasured(h.id, J),
            )
            for h in sc.humans
        ]
        self._hist_t: list[float] = []
        self._hist_y: list[list[np.ndarray]] = [[] for _ in sc.humans]
        self._parts = reach.skeleton.part_joints
        self._half_th = self.params.half_thickness_m
        self.t = 0.0
        self.cycles = 0
        self.collisions = 0
        self.first_collision_s: float | None = None
        self.min_sep = math.inf
        self.min_sep_moving = math.inf
        self.time_to_goal_s: float | None = None
        self.cycle_us: list[float] = []
        self.modes: dict[str, int] = {}
        self.last: CycleResult | None = None
        self.true_poses: list[np.ndarray] = []

    # -- parts of a step ---------------------------------------------------------------------

    def _sense(self, t: float, i: int) -> None:
        sen = self.sensors[i]
        if t + 1e-12 < sen.next_s:
            return
        sen.next_s += 1.0 / sen.rate_hz
        if sen.next_s <= t:
            sen.next_s = t + 1.0 / sen.rate_hz
        t_target = t - self.params.delay_s
        k = int(np.searchsorted(self._hist_t, t_target + 1e-12, side="right")) - 1
        if k < 0:
            return
        t_m = self._hist_t[k]
        y = self._hist_y[i][k]
        y = measured(y, sen.noise_m, self.rng)
        stamp = t_m + self.params.delay_s
        if sen.state.stamp_s is not None and stamp <= sen.state.stamp_s:
            return
        v, dv = sen.estimator.update(stamp, y)
        sen.state.y, sen.state.v, sen.state.dv = y, v.copy(), dv.copy()
        sen.state.stamp_s = stamp

    def _collide(self, q: np.ndarray, poses: list[np.ndarray], moving: bool) -> None:
        if not poses:
            return
        ends, rad = self.truth_robot.link_capsules(q)
        for y in poses:
            dmin = body_distance(y, self._parts, self._half_th, ends, rad)
            self.min_sep = min(self.min_sep, dmin)
            if moving:
                self.min_sep_moving = min(self.min_sep_moving, dmin)
                if dmin <= 0.0:
                    self.collisions += 1
                    if self.first_collision_s is None:
                        self.first_collision_s = self.t

    def step(self) -> None:
        t = self.t
        shield = self.shield
        q = shield.robot_state.q
        ends, rad = self.robot.link_capsules(q)
        poses = [m.pose(t, ends, rad) for m in self.motions]
        if not self._hist_t:
            # the people stood still before the start: the sensors have a first frame at once
            self._hist_t.append(t - self.params.delay_s - self.dt)
            for i, y in enumerate(poses):
                self._hist_y[i].append(y)
        self._hist_t.append(t)
        for i, y in enumerate(poses):
            self._hist_y[i].append(y)
            self._sense(t, i)
        moving = bool(np.max(np.abs(shield.robot_state.v), initial=0.0) > _MOVING_RAD_S)
        self._collide(q, poses, moving)
        res = self.shield.cycle(t, [s.state for s in self.sensors], None, want_distance=False)
        self.last = res
        self.cycle_us.append(res.cycle_time_us)
        self.modes[res.mode] = self.modes.get(res.mode, 0) + 1
        self.cycles += 1
        self.t = t + self.dt
        if shield.task_done and self.time_to_goal_s is None:
            nxt = self.cell.next_pass(self.pass_index, loop=False)
            if nxt is not None:
                self.pass_index = nxt
                shield.follower.replan(self.cell.passes[nxt])
            else:
                self.time_to_goal_s = self.t

    def run(self, duration_s: float | None = None, progress: bool = False) -> SimMetrics:
        T = self.scenario.sim.duration_s if duration_s is None else duration_s
        n = int(round(T / self.dt))
        tick = max(1, n // 40)
        for k in range(n):
            self.step()
            if progress and (k % tick == 0 or k == n - 1):
                done = (k + 1) / n
                bar = "#" * int(40 * done)
                print(
                    f"\r[{bar:<40s}] {100 * done:5.1f} %  t = {self.t:6.2f} s",
                    end="",
                    file=sys.stderr,
                    flush=True,
                )
        if progress:
            print(file=sys.stderr)
        return self.metrics()

    def metrics(self) -> SimMetrics:
        cu = np.array(self.cycle_us) if self.cycle_us else np.zeros(1)
        fs = self.modes.get("failsafe", 0) + self.modes.get("fault", 0)
        return SimMetrics(
            scenario=self.scenario.name,
            duration_s=self.t,
            cycles=self.cycles,
            collisions_moving=self.collisions,
            first_collision_s=self.first_collision_s,
            min_separation_m=self.min_sep,
            min_separation_moving_m=self.min_sep_moving,
            failsafe_share=fs / max(self.cycles, 1),
            fault_cycles=self.modes.get("fault", 0),
            time_to_goal_s=self.time_to_goal_s,
            cycle_us_p50=float(np.median(cu)),
            cycle_us_p99=float(np.percentile(cu, 99)),
            modes=dict(self.modes),
        )
