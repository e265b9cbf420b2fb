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

PFL ground truth (:class:`ContactTruth`, evaluated in every mode, so SSM runs report it too): a
contact between a true body part and robot link ``i`` is allowed when the link's true kinetic
energy (eq. 46, ``1/2 q_dot^T E_i B(q) E_i q_dot`` of the executed motion) is below the threshold
of the contact's ACTUAL class. It is clamped when the body part, or a body part stacked with it
(touching it and not a safe pair, transitively, as in Thumm et al. 2024 eq. 39-43, other people's
parts included), touches an environment box or a robot link that can clamp with ``i`` (not ``i``,
not declared unclampable with it); the threshold is then the smallest constrained one of the stack,
else the part's unconstrained one. This truth ignores the velocity relaxation (a link moving
away from the table is still taken as clamping), so it is stricter than the shield's check. A
contact whose energy reaches that threshold is harmful (``SimMetrics.harmful_contacts``).
"""

from __future__ import annotations

import bisect
import math
import sys
from dataclasses import dataclass, field

import numpy as np

from sara_app.cell.build import build_cell, environment_boxes
from sara_app.cell.intake import Track, take_measurement, track_for
from sara_app.geometry.shapes import capsule_box_distances, segment_pair_distances
from sara_app.human.glitches import Glitches
from sara_app.human.params import ReachParams
from sara_app.human.skeleton import UPPER_JOINTS, full_body
from sara_app.robot.energy import LinkMotion
from sara_app.robot.model import RobotModel
from sara_app.safety.settings import PflSettings
from sara_app.safety.shield import CycleResult
from sara_app.safety.ssm import body_distance
from sara_app.safety.thresholds import threshold_arrays
from sara_app.safety.topology import human_safe_matrix, unclampable_matrix
from sara_app.scenario import Scenario
from sara_app.sim.motions import HumanMotion, make_motion, measured, measures_legs

_MOVING_RAD_S = 1e-6


@dataclass
class _Sensor:
    rate_hz: float
    noise_m: float
    next_s: float
    glitches: Glitches
    track: Track
    legs_measured: bool = True


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
    safety_mode: str = "ssm"
    harmful_contacts: int = 0
    """Steps x people with a contact whose link energy reaches its actual class's threshold."""
    first_harmful_s: float | None = None
    contacts_moving: int = 0
    """Steps x people touching a robot link that has kinetic energy (PFL allows these)."""
    clamped_contacts: int = 0
    """Of those, the ones in a clamping configuration (actual class constrained)."""
    max_energy_ratio: float = 0.0
    """Largest link energy / actual threshold over all contacts (harmful from 1 on)."""
    speed_scale_mean: float = 1.0
    intervened_share: float = 0.0
    tracking: dict[str, int] = field(default_factory=dict)
    """Flags of the tracking gate and the conformance monitor, summed over people
    (``sara_app.human.intake``); ``refused``: skeletons refused for a joint held too long."""

    def lines(self) -> list[str]:
        ttg = f"{self.time_to_goal_s:.2f} s" if self.time_to_goal_s is not None else "not reached"
        return [
            f"scenario            {self.scenario} ({self.safety_mode})",
            f"simulated           {self.duration_s:.2f} s, {self.cycles} cycles",
            f"collisions moving   {self.collisions_moving}"
            + (f" (first at {self.first_collision_s:.3f} s)" if self.first_collision_s else ""),
            f"min separation      {self.min_separation_m:.3f} m "
            f"(while moving {self.min_separation_moving_m:.3f} m)",
            f"failsafe share      {100 * self.failsafe_share:.1f} % of cycles"
            f" (faults: {self.fault_cycles})",
            f"contacts (energy)   {self.contacts_moving} touching a moving link, "
            f"{self.clamped_contacts} clamped, {self.harmful_contacts} harmful"
            + (f" (first at {self.first_harmful_s:.3f} s)" if self.first_harmful_s else "")
            + f"; largest energy/threshold {self.max_energy_ratio:.3f}",
            f"intervened          {100 * self.intervened_share:.1f} % of cycles"
            f" (mean speed scale {self.speed_scale_mean:.2f})",
            f"time to goal        {ttg}",
            "tracking flags      "
            + (", ".join(f"{k} {v}" for k, v in self.tracking.items() if v) or "none"),
            f"shield cycle        p50 {self.cycle_us_p50:.0f} us, p99 {self.cycle_us_p99:.0f} us",
            "modes               " + ", ".join(f"{k} {v}" for k, v in sorted(self.modes.items())),
        ]


@dataclass
class ContactVerdict:
    """Per person: ``touching`` a link with energy, ``clamped`` (actual class), ``harmful``
    (energy >= threshold of the actual class); ``ratio`` the largest energy / threshold."""

    touching: np.ndarray
    clamped: np.ndarray
    harmful: np.ndarray
    ratio: np.ndarray


class ContactTruth:
    """Ground truth of PFL contacts for ``n_humans`` people (see the module notes).

    ``part_joints (P, 2)``, ``half_th (P,)`` m, ``part_names (P,)`` of the skeleton; thresholds
    from ``spec`` (a scenario's :class:`PflSettings`); ``boxes`` the environment
    ``(T_world_box (B, 4, 4), half_extents_m (B, 3))``.
    """

    def __init__(
        self,
        robot: RobotModel,
        part_joints: np.ndarray,
        half_th: np.ndarray,
        part_names: tuple[str, ...],
        n_humans: int,
        spec: PflSettings,
        boxes: tuple[np.ndarray, np.ndarray],
    ) -> None:
        H, P = n_humans, len(part_names)
        self.robot, self.n_humans, self.n_parts = robot, H, P
        self.motion = LinkMotion(robot)
        T_free, T_clamp = threshold_arrays(
            spec.edited_set()[0], robot.link_names, part_names, spec.link_shapes
        )
        self.T_free, self.T_clamp = np.tile(T_free, (1, H)), np.tile(T_clamp, (1, H))
        L = robot.n_links
        declared = unclampable_matrix(robot.name, robot.link_names, spec.unclampable_pairs)
        self.no_clamp = declared | np.eye(L, dtype=bool)
        owner = np.repeat(np.arange(H), P)
        self.owner = owner
        self.safe_pair = human_safe_matrix(list(part_names) * H, owner) | np.eye(H * P, dtype=bool)
        self.part_joints, self.half_th = part_joints, np.tile(half_th, H)
        self.boxes = boxes
        # index pairs, built once: every (link, part) and the part pairs that may stack
        self._rl, self._rp = (x.ravel() for x in np.meshgrid(np.arange(L), np.arange(H * P)))
        self._pa, self._pb = np.nonzero(np.triu(~self.safe_pair))

    def evaluate(self, q: np.ndarray, v: np.ndarray, poses: list[np.ndarray]) -> ContactVerdict:
        """Contacts of the robot at ``q, v (n,)`` with the people's true joints ``(J, 3)``."""
        H = len(poses)
        none = np.zeros(H, dtype=bool)
        verdict = ContactVerdict(none, none.copy(), none.copy(), np.zeros(H))
        r_ends, r_rad = self.robot.link_capsules(q)
        h_ends = np.concatenate([y[self.part_joints] for y in poses])  # (H P, 2, 3)
        rl, rp, ht = self._rl, self._rp, self.half_th
        d = segment_pair_distances(r_ends[rl], h_ends[rp]) - r_rad[rl] - ht[rp]
        touch_any = np.zeros((len(r_rad), len(ht)), dtype=bool)  # (L, H P)
        touch_any[rl, rp] = d <= 0.0
        if not touch_any.any():
            return verdict
        E = self.motion.energies(q[None], v[None])[0]  # (L,) J
        touch = touch_any & (E[:, None] > 0.0)  # a link without energy cannot hurt
        if not touch.any():
            return verdict
        on_box = np.zeros(len(h_ends), dtype=bool)
        if self.boxes[0].shape[0]:
            d_box = capsule_box_distances(h_ends, self.half_th, *self.boxes)  # (H P, B)
            on_box = np.asarray((d_box <= 0.0).any(axis=1))
        pa, pb = self._pa, self._pb
        stack = np.eye(len(h_ends), dtype=bool)
        near = segment_pair_distances(h_ends[pa], h_ends[pb]) - ht[pa] - ht[pb] <= 0.0
        stack[pa[near], pb[near]] = stack[pb[near], pa[near]] = True
        for _ in range(len(h_ends)):  # transitive closure (small P)
            nxt = (stack.astype(np.int32) @ stack.astype(np.int32)) > 0
            if np.array_equal(nxt, stack):
                break
            stack = nxt
        # every touching (link i, part j) pair at once: j's stack (it is one of its members)
        # clamps when a member is on a box or touches a link that can clamp with i
        i, j = np.nonzero(touch)
        members = stack[j]  # (N, H P)
        links_on_stack = members @ touch_any.T  # (N, L) booleans: a link touches a member
        clamped = (members & on_box).any(axis=1) | (links_on_stack & ~self.no_clamp[i]).any(1)
        T_stack = np.where(members, self.T_clamp[i], np.inf).min(axis=1)  # the stack's lowest
        ratio = E[i] / np.where(clamped, T_stack, self.T_free[i, j])
        h = self.owner[j]
        verdict.touching[h] = True
        np.logical_or.at(verdict.clamped, h, clamped)
        np.logical_or.at(verdict.harmful, h, ratio >= 1.0)
        np.maximum.at(verdict.ratio, h, ratio)
        return verdict


class Simulation:
    """One scenario in closed loop. ``step()`` advances one control cycle."""

    def __init__(self, sc: Scenario, motion_params: ReachParams | None = None) -> None:
        """``motion_params``: the bounds scripted and adversarial people move within (None:
        the scenario's own set; a what-if passes the set in force, so that an edited human
        model changes what the cell assumes, not how the people move)."""
        self.scenario = sc
        cell = build_cell(sc)
        self.robot: RobotModel = cell.robot
        self.truth_robot = (
            cell.robot
            if sc.robot.margin_m == 0
            else sc.robot.load(cell.robot.T_world_base, margin=False)
        )
        self.cell = cell
        self.pass_index = 0
        self.params = cell.params
        reach = cell.shield.reach
        self.shield = cell.shield
        s = sc.shield
        self.dt = s.dt_s
        self.rng = np.random.default_rng(sc.sim.seed)
        moves = self.params if motion_params is None else motion_params
        self.motions: list[HumanMotion] = [make_motion(h, moves) for h in sc.humans]
        self.sensors = [
            _Sensor(
                h.sensor.rate_hz,
                h.sensor.noise_m,
                0.0,
                Glitches(h.sensor.glitches),
                track_for(cell, h.id),
                measures_legs(m, h.sensor.tracks),
            )
            for h, m in zip(sc.humans, self.motions)
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
        self.separation_m = math.inf
        """The smallest true body-robot distance of the last step (inf: nobody)."""
        self.poses: list[np.ndarray] = []
        """Every person's true joints ``(J, 3)`` at the last step."""
        self.min_sep_moving = math.inf
        self.time_to_goal_s: float | None = None
        self.cycle_us: list[float] = []
        self.modes: dict[str, int] = {}
        self.last: CycleResult | None = None
        self.true_poses: list[np.ndarray] = []
        self.truth = ContactTruth(
            self.truth_robot,
            self._parts,
            self._half_th,
            reach.skeleton.parts,
            len(sc.humans),
            sc.shield.pfl,
            environment_boxes(sc),
        )
        self.harmful = self.contacts = self.clamped = 0
        self.first_harmful_s: float | None = None
        self.max_energy_ratio = 0.0
        self._scale_sum = 0.0
        self._intervened = 0

    # -- parts of a step ---------------------------------------------------------------------

    def _sense(self, t: float, i: int) -> None:
        sen = self.sensors[i]
        if t + 1e-12 < sen.next_s:
            return
        sen.next_s += 1.0 / sen.rate_hz
        if sen.next_s <= t:
            sen.next_s = t + 1.0 / sen.rate_hz
        t_target = t - self.params.delay_s
        # bisect on the list: np.searchsorted would copy the whole growing history each call
        k = bisect.bisect_right(self._hist_t, t_target + 1e-12) - 1
        if k < 0:
            return
        t_m = self._hist_t[k]
        y = self._hist_y[i][k]
        y = sen.glitches.apply(t_m, measured(y, sen.noise_m, self.rng))
        stamp = t_m + self.params.delay_s
        if sen.track.state.stamp_s is not None and stamp <= sen.track.state.stamp_s:
            return
        if not sen.legs_measured:  # an upper-body source: its legs at the pelvis, unmeasured
            y = full_body(y[: len(UPPER_JOINTS)], None)[0]
        take_measurement(self.cell, sen.track, stamp, y, legs_measured=sen.legs_measured)

    def _collide(
        self,
        q: np.ndarray,
        v: np.ndarray,
        poses: list[np.ndarray],
        moving: bool,
        capsules: tuple[np.ndarray, np.ndarray],
    ) -> None:
        """``capsules``: the cell robot's link capsules at ``q``, the truth's where the robot
        has no margin (the same model)."""
        if not poses:
            return
        truth = self.truth_robot
        ends, rad = capsules if truth is self.robot else truth.link_capsules(q)
        touching = False
        for y in poses:
            dmin = body_distance(y, self._parts, self._half_th, ends, rad)
            self.separation_m = min(self.separation_m, dmin)
            self.min_sep = min(self.min_sep, dmin)
            if moving:
                self.min_sep_moving = min(self.min_sep_moving, dmin)
                if dmin <= 0.0:
                    touching = True
                    self.collisions += 1
                    if self.first_collision_s is None:
                        self.first_collision_s = self.t
        if touching:
            self._judge(q, v, poses)

    def _judge(self, q: np.ndarray, v: np.ndarray, poses: list[np.ndarray]) -> None:
        """PFL ground truth of the contacts now (see :class:`ContactTruth`)."""
        c = self.truth.evaluate(q, v, poses)
        self.contacts += int(c.touching.sum())
        self.clamped += int(c.clamped.sum())
        n = int(c.harmful.sum())
        self.harmful += n
        if n and self.first_harmful_s is None:
            self.first_harmful_s = self.t
        self.max_energy_ratio = max(self.max_energy_ratio, float(c.ratio.max(initial=0.0)))

    def step(self) -> None:
        t = self.t
        shield = self.shield
        q = shield.robot_state.q
        ends, rad = self.robot.link_capsules(q)
        poses = [m.pose(t, ends, rad) for m in self.motions]
        self.poses = poses
        if not self._hist_t:
            # the people stood still before the start: the sensors have a first frame at once
            self._hist_t.append(t - self.params.delay_s - self.dt)
            for i, y in enumerate(poses):
                self._hist_y[i].append(y)
        self._hist_t.append(t)
        for i, y in enumerate(poses):
            self._hist_y[i].append(y)
            self._sense(t, i)
        v = shield.robot_state.v
        moving = bool(np.max(np.abs(v), initial=0.0) > _MOVING_RAD_S)
        self.separation_m = math.inf
        self._collide(q, v, poses, moving, (ends, rad))
        faults = [f for f in (s.track.intake.fault(s.track.state.id) for s in self.sensors) if f]
        res = self.shield.cycle(
            t, [s.track.state for s in self.sensors], None, input_faults=faults, want_distance=False
        )
        self.last = res
        self._scale_sum += res.speed_scale
        self._intervened += res.intervened
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
            safety_mode=self.shield.safety_mode,
            harmful_contacts=self.harmful,
            first_harmful_s=self.first_harmful_s,
            contacts_moving=self.contacts,
            clamped_contacts=self.clamped,
            max_energy_ratio=self.max_energy_ratio,
            speed_scale_mean=self._scale_sum / max(self.cycles, 1),
            intervened_share=self._intervened / max(self.cycles, 1),
            tracking=self.tracking_counts(),
        )

    def tracking_counts(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for s in self.sensors:
            for k, v in s.track.intake.counts().items():
                out[k] = out.get(k, 0) + v
        return out
