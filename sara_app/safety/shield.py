"""The safety shield: every cycle, verify one intended step + failsafe, else brake on the last
verified failsafe (Pereira & Althoff 2016 Sec. II, Schepp et al. 2022 Sec. II-C, Thumm et al. 2024
Sec. III-B).

Induction: the follower always holds a failsafe stop that was verified, together with the step
that led to it, against human sets that cover the whole stop (the sets grow from the measurement
time to the end of the stop). A cycle commits the intended step only if the new shielded
trajectory (step + its own stop) verifies; otherwise it advances along the held stop, which
stays verified. So the robot is always on a verified motion or at rest.

Assumptions (Thumm et al. 2024 Sec. V), stated here because the guarantee rests on them:

- a robot at rest cannot hurt a person (SSM: contact with a resting robot is allowed);
- the tracking system sees every person in the cell; a person's skeleton stamped ``t`` shows
  the pose at ``t - delay`` within ``delta_y`` per joint; every enabled model's bounds hold for
  that person (see the parameter set's ``sound_for``);
- the controller tracks the commanded joint trajectory within ``tracking_tol_rad`` per joint
  (checked every cycle against the measured state; beyond it is a fault);
- clocks of sensor and cell agree (a measurement from the future is a fault).

Faults (stale, missing, malformed or future skeletons; tracking error; a planning failure)
never raise: the cycle brakes along the held failsafe and reports them.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from sara_app.errors import InputError, ParameterError, SaraError
from sara_app.human.reach import MODELS, HumanReach
from sara_app.kernel_types import as_f8, entry
from sara_app.robot.deviation_kernels import max_abs_diff
from sara_app.robot.failsafe import BOUND_PAD
from sara_app.robot.model import RobotModel
from sara_app.robot.occupancy import RobotOccupancy
from sara_app.robot.path import waypoints_ahead
from sara_app.robot.planning_kernels import OUT_LEN
from sara_app.robot.shielded import ShieldedTrajectory, from_samples, shielded_trajectory
from sara_app.robot.trajectory import JointState, PathFollower
from sara_app.safety.distance_kernels import min_distance_kernel
from sara_app.safety.input_kernels import BAD_BOUND, NON_FINITE, human_values
from sara_app.safety.settings import FUTURE_TOLERANCE_S, ShieldSettings
from sara_app.safety.ssm import SsmResult, SsmVerifier
from sara_app.safety.ssm_cycle_kernels import DONE, ssm_cycle_kernel
from sara_app.safety.ssm_kernels import model_verdicts

MODES = ("intended", "failsafe", "rest", "fault")

Humans = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None, np.ndarray | None]
"""The usable people of a cycle: ``y, v (H, J, 3)``, ``dv (H, J)``, ``age (H,)``, the
widening ``(H, len(MODELS), P)`` of :mod:`sara_app.human.widening` (None: none) and the height
bounds of unmeasured legs ``(H, P, 2)`` of :mod:`sara_app.human.legs` (None: none)."""


@dataclass
class HumanState:
    """One person's latest measurement: joints ``y (J, 3)`` m, velocity ``v (J, 3)`` m/s with
    error bound ``dv (J,)`` m/s, sensor time stamp ``stamp_s`` (``None``: never measured);
    ``widen_m``: extra set radius per model and body part ``(len(MODELS), P)`` m
    (:mod:`sara_app.human.widening`; None: none); ``leg_cap (P, 2)``: the height bound of
    each body part, for legs the tracker does not measure (:func:`~sara_app.human.legs.leg_caps`;
    None: none)."""

    id: str
    y: np.ndarray
    v: np.ndarray
    dv: np.ndarray
    stamp_s: float | None
    widen_m: np.ndarray | None = None
    leg_cap: np.ndarray | None = None

    @classmethod
    def unmeasured(cls, human_id: str, n_joints: int) -> HumanState:
        """A person announced but not measured yet (a fault until the first measurement)."""
        J = n_joints
        return cls(human_id, np.zeros((J, 3)), np.zeros((J, 3)), np.full(J, np.inf), None)


@dataclass
class CycleResult:
    """What one cycle decided. ``command``: the joint state at the end of the executed step;
    ``trajectory`` / ``robot_ends (K, L, 2, 3)`` / ``robot_radius (K, L)``: the shielded
    trajectory that was checked (``None`` if none could be planned); ``model_free``: per model,
    True/False when evaluated on every interval, absent otherwise."""

    t_s: float
    mode: str
    verified: bool
    command: JointState
    faults: list[str] = field(default_factory=list)
    model_free: dict[str, bool] = field(default_factory=dict)
    ages_s: dict[str, float] = field(default_factory=dict)
    min_distance_m: float | None = None
    cycle_time_us: float = 0.0
    trajectory: ShieldedTrajectory | None = None
    robot_ends: np.ndarray | None = None
    robot_radius: np.ndarray | None = None
    ssm: SsmResult | None = None
    safety_mode: str = "ssm"
    intervened: bool = False
    """The safety layer changed the nominal motion this cycle (failsafe, slower, filtered)."""
    speed_scale: float = 1.0
    """SSM and PFL: the path-speed cap used, as a fraction of the admissible speed (1: none)."""
    pfl: Any = None
    """PFL mode: the :class:`~sara_app.safety.pfl.PflResult` of the executed trajectory."""
    jssa: Any = None
    """JSSA mode: the :class:`~sara_app.safety.jssa.JssaResult` of this cycle."""
    human_ids: list[str] = field(default_factory=list)
    """The humans the cycle used, in the order of the per-human axes of its results."""


class Shield:
    """SSM shield around a :class:`PathFollower` (which it owns and advances).

    Other safety modes subclass it and override :meth:`_plan_and_verify` (plan a shielded
    trajectory, verify it; the commit/brake logic and the fault handling stay here)."""

    safety_mode = "ssm"
    holds_failsafe = True
    """Whether the mode holds a verified failsafe every cycle (JSSA does not: a switch from it to
    another mode waits for the robot at rest, braking meanwhile: :attr:`halt_reason`)."""
    halt_reason: str | None = None
    """Set on a mode without a verified failsafe while a switch waits for rest (every cycle
    brakes); the modes that hold a failsafe never need it."""

    def blocking(self, res: CycleResult, limit: int = 8) -> list[str]:
        """``"<person> <body part>"`` for each body part the check could not clear on some
        interval of the cycle's checked trajectory (why it brakes or slows), at most ``limit``;
        empty where the mode's result says nothing per body part (PFL, JSSA) or all cleared."""
        if res.ssm is None or res.ssm.safe or not res.human_ids:
            return []  # safe: every part cleared on every interval (SsmResult)
        blocked = ~np.asarray(res.ssm.parts_clear).all(axis=1)  # (H, P)
        names = self.reach.skeleton.parts
        return [f"{res.human_ids[h]} {names[p]}" for h, p in zip(*np.nonzero(blocked))
                if h < len(res.human_ids)][:limit]  # fmt: skip

    def __init__(
        self,
        robot: RobotModel,
        follower: PathFollower,
        reach: HumanReach,
        settings: ShieldSettings | None = None,
    ) -> None:
        self.settings = s = settings or ShieldSettings()
        self.robot = robot
        self.follower = follower
        self.reach = reach
        self.verifier = SsmVerifier(reach, s.models)
        self.occupancy = RobotOccupancy(robot)
        # Tracking error up to tol per joint moves a link point by at most sum_j L[i, j] tol.
        self.tracking_margin_m = self.occupancy.lipschitz @ np.full(robot.n_dof, s.tracking_tol_rad)
        self._compiled = _compiled_inputs(self.verifier, self.occupancy, self.tracking_margin_m,
                                          s.max_interval_s)  # fmt: skip
        self._info = np.empty(6)
        self._peek_record = np.empty(OUT_LEN)  # the cycle kernel's last peek_kernel record
        self._verdicts = np.empty((2, len(self.verifier.models)), np.bool_)  # _annotate's
        self._half_th = reach.params.half_thickness_m
        self._parts = np.asarray(reach.skeleton.part_joints, dtype=np.int64)
        self._n_joints = reach.skeleton.n_joints
        self._distance_inputs = _distance_inputs(self.occupancy, robot.radius_m)
        half, radius = as_f8(self._half_th), self._distance_inputs[-1]
        ok = half.shape == (len(self._parts),)  # else min_distance raises, as it checks them
        self._distance = {w: (w and ok, radius, self._parts, half if ok else radius[:0])
                          for w in (False, True)}  # fmt: skip
        """The cycle kernel's separation inputs (:data:`ssm_cycle_kernels.DISTANCE`), asked
        for or not."""
        self._separation: float | None = None
        """The separation at the checked plan's sample 1 (the command when it is committed)
        from this cycle's compiled call; None where it did not compute it."""
        self._want_distance = True
        self._no_widening = np.zeros((1, len(MODELS), reach.skeleton.n_parts))
        self._commanded: tuple[PathFollower, float, np.ndarray] | None = None
        self.cycles = 0
        self.fault_cycles = 0
        self.failsafe_cycles = 0
        self._scale = 1.0

    @property
    def robot_state(self) -> JointState:
        """The commanded joint state now (the end of the last executed step)."""
        return self.follower.state

    @property
    def task_done(self) -> bool:
        """At rest at the end of the current path (the task may then replan the follower)."""
        return self.follower.done

    @property
    def at_rest(self) -> bool:
        return self.follower.sd <= 1e-9 and abs(self.follower.sdd) <= 1e-7

    def brake_step(self) -> JointState:
        """One cycle along the held verified failsafe, outside :meth:`cycle` (the worker's last
        line of defence when a cycle raised)."""
        return self.follower.brake(self.settings.dt_s)

    def with_energies(self, result: Any, traj: ShieldedTrajectory) -> Any:
        """A contact check's ``result`` with the link energies over ``traj`` for display (PFL
        fills them in where its check skipped them; the other modes have none to add)."""
        return result

    def adopt(self, previous: Shield) -> None:
        """Take the robot over from the safety layer that ran it until now (same robot).

        From SSM or PFL the follower is kept with the failsafe it holds: that stop was verified
        under the previous mode's criterion, which therefore still covers the robot until the
        new mode commits its first verified step (SSM -> PFL: an SSM-verified stop touches
        nobody, so it is PFL-safe too; PFL -> SSM: the held stop may allow contacts below the
        energy thresholds until then). From JSSA nothing was verified: the robot must be at
        rest; the new follower then starts where it stands (on or off the old path) and goes on
        through the old path's waypoints ahead of it. Raises :class:`ParameterError` otherwise.
        """
        f = previous.follower
        now = previous.robot_state
        if previous.safety_mode != "jssa":
            on_path = f.state
            if np.allclose(now.q, on_path.q, atol=1e-9) and np.allclose(
                now.v, on_path.v, atol=1e-9
            ):
                self.follower = f
                return
        if not previous.at_rest:
            raise ParameterError(
                f"switching from {previous.safety_mode} to {self.safety_mode} needs the robot "
                f"at rest ({previous.safety_mode} holds no verified failsafe for it); stop "
                "it first"
            )
        self._start_at(f, now.q, None)

    def restart_from(self, q: np.ndarray, waypoints: np.ndarray | None = None) -> None:
        """The robot rests at ``q`` (measured), not where the follower rests: follow from there
        through the waypoints of the current path (or ``waypoints (W, n)``) still ahead of it
        to their end. Raises :class:`ParameterError` unless at rest."""
        if not self.at_rest:
            raise ParameterError("the follower can restart from a measured state only at rest")
        self._start_at(self.follower, np.asarray(q, dtype=float), waypoints)
        self._commanded = None

    def _start_at(self, f: PathFollower, q: np.ndarray, waypoints: np.ndarray | None) -> None:
        """A new follower from ``q`` at rest through the waypoints ahead of it
        (:func:`~sara_app.robot.path.waypoints_ahead`) of ``f``'s path or ``waypoints``: it went
        straight to the path's end, across the corners the task goes around."""
        wps = f.path.waypoints if waypoints is None else np.asarray(waypoints, dtype=float)
        ahead = waypoints_ahead(wps, q)
        at_end = np.allclose(q, ahead[-1], atol=1e-9)  # then it rests there
        points = ahead[-1:] if at_end else np.vstack([q, ahead])
        self.follower = PathFollower(points, f.limits, blend_distance=f.blend_distance)

    # -- checks ---------------------------------------------------------------------------------

    def _check_tracking(self, measured: JointState | None, faults: list[str]) -> None:
        if measured is None:
            return
        q = np.asarray(measured.q, dtype=float)
        expected = self._commanded_q()
        if q.shape != expected.shape or not math.isfinite(float(q.sum())):
            faults.append(f"robot state malformed: q shape {q.shape}, expected {expected.shape}")
            return
        err = max_abs_diff(q, expected)
        if err > self.settings.tracking_tol_rad:
            faults.append(
                f"tracking error {err:.4f} rad > tolerance {self.settings.tracking_tol_rad} rad"
            )

    def _commanded_q(self) -> np.ndarray:
        """``(n,)`` the joint position last commanded (what a measured state must track)."""
        f = self.follower
        cached = self._commanded
        if cached is not None and cached[0] is f and cached[1] == f.s:
            return cached[2]  # the last command: the follower still stands where it left it
        return f.path.q(f.s)

    def _count(self, mode: str) -> None:
        """Per-mode cycle counters."""
        self.cycles += 1
        self.fault_cycles += mode == "fault"
        self.failsafe_cycles += mode in ("failsafe", "fault")

    def _check_humans(
        self, t_now: float, humans: list[HumanState], faults: list[str], ages: dict[str, float]
    ) -> list[int]:
        """Indices of usable humans; a human that is not usable is a fault."""
        ok = []
        J = self._n_joints
        s = self.settings
        for i, h in enumerate(humans):
            if h.stamp_s is None or not math.isfinite(h.stamp_s):
                faults.append(f"human {h.id!r}: no measurement")
                continue
            age = t_now - h.stamp_s
            ages[h.id] = age
            y, v, dv = as_f8(h.y), as_f8(h.v), as_f8(h.dv)
            shapes = (y.shape, v.shape, dv.shape)
            code = _HUMAN_VALUES(y, v, dv) if shapes == ((J, 3), (J, 3), (J,)) else -1
            if code == -1:
                faults.append(f"human {h.id!r}: arrays {shapes}, expected ({J}, 3) and ({J},)")
            elif code == NON_FINITE:
                faults.append(f"human {h.id!r}: non-finite joint positions or velocities")
            elif code == BAD_BOUND:  # negative or NaN
                faults.append(f"human {h.id!r}: velocity error bound invalid")
            elif age > s.skeleton_timeout_s:
                faults.append(f"human {h.id!r}: skeleton {age:.3f} s old > {s.skeleton_timeout_s}")
            elif age < -FUTURE_TOLERANCE_S:
                faults.append(f"human {h.id!r}: skeleton stamped {-age:.4f} s in the future")
            else:
                ok.append(i)
        return ok

    # -- the cycle ------------------------------------------------------------------------------

    def cycle(
        self,
        t_now: float,
        humans: list[HumanState],
        measured: JointState | None = None,
        *,
        want_distance: bool = True,
        input_faults: list[str] | None = None,
    ) -> CycleResult:
        """One control cycle at cell time ``t_now``; advances the follower by ``dt_s``."""
        t0 = time.perf_counter()
        faults: list[str] = list(input_faults or ())  # the cell's inputs (trackers, robot)
        ages: dict[str, float] = {}
        self._check_tracking(measured, faults)
        usable = self._check_humans(t_now, humans, faults, ages)
        traj = ends = radius = None
        verified = False
        self._res: Any = None
        self._separation, self._want_distance = None, bool(want_distance)
        try:
            if not faults:
                traj, ends, radius, verified = self._plan_and_verify(
                    self._human_arrays(humans, usable, ages)
                )
            else:
                traj, ends, radius = self._shielded()
        except SaraError as e:  # a planning or input failure is an unsafe cycle, not a crash
            faults.append(f"cycle failed: {e}")
            verified = False
        res = self._res
        follower = self.follower
        at_end = None
        if verified and traj is not None:
            at_end = JointState(traj.q[1], traj.v[1], traj.a[1])
            command = follower.commit(traj.step, at_end)
            mode = "failsafe" if traj.step.fallback else "intended"
        else:
            command = follower.brake(self.settings.dt_s)
            mode = "fault" if faults else "failsafe"
        self._commanded = (follower, follower.s, command.q)
        if mode != "fault" and follower.sd <= 1e-9 and abs(follower.sdd) <= 1e-7:
            mode = "rest" if (follower.done or verified) else mode
        self._count(mode)
        out = CycleResult(
            t_s=t_now,
            mode=mode,
            verified=verified,
            command=command,
            faults=faults,
            ages_s=ages,
            trajectory=traj,
            robot_ends=ends,
            robot_radius=radius,
            safety_mode=self.safety_mode,
            human_ids=[humans[i].id for i in usable] if not faults else [],
        )
        out.intervened = mode in ("failsafe", "fault")
        self._annotate(out, res)
        if want_distance and usable:
            sep = self._separation  # the compiled cycle's, at the plan's sample 1
            if sep is None or command is not at_end:  # none, or the command is not that sample
                sep = self.min_distance(command.q, [humans[i].y for i in usable])
            out.min_distance_m = sep
        out.cycle_time_us = (time.perf_counter() - t0) * 1e6
        return out

    # -- hooks of the safety modes --------------------------------------------------------------

    def _human_arrays(
        self, humans: list[HumanState], usable: list[int], ages: dict[str, float]
    ) -> Humans | None:
        """Usable humans stacked: ``y, v (H, J, 3)``, ``dv (H, J)``, ``age (H,)``, ``widen
        (H, len(MODELS), P)``, ``caps (H, P, 2)``; None if none."""
        if not usable:
            return None
        if len(usable) == 1:  # the common case, without the copies of a stack
            h = humans[usable[0]]
            w = None if h.widen_m is None else h.widen_m[None]  # None: no widening
            c = None if h.leg_cap is None else h.leg_cap[None]
            return h.y[None], h.v[None], h.dv[None], np.array([max(ages[h.id], 0.0)]), w, c
        y = np.stack([humans[i].y for i in usable])
        v = np.stack([humans[i].v for i in usable])
        dv = np.stack([humans[i].dv for i in usable])
        age = np.array([max(ages[humans[i].id], 0.0) for i in usable])
        widen = np.zeros((len(usable),) + self._no_widening.shape[1:])
        caps = None
        for k, i in enumerate(usable):
            widen_i, cap_i = humans[i].widen_m, humans[i].leg_cap
            if widen_i is not None:
                widen[k] = widen_i
            if cap_i is not None:
                if caps is None:
                    caps = np.zeros((len(usable),) + cap_i.shape)
                    caps[:, :, 0] = np.inf
                caps[k] = cap_i
        return y, v, dv, age, widen, caps

    def _shielded(self) -> tuple[ShieldedTrajectory, np.ndarray, np.ndarray]:
        """The follower's next shielded trajectory and its robot capsules per interval
        ``(K, L, 2, 3)``, ``(K, L)`` (tracking margin included)."""
        traj = shielded_trajectory(
            self.follower, self.settings.dt_s, max_interval_s=self.settings.max_interval_s
        )
        ends, radius = self.occupancy.intervals_of(traj)
        radius += self.tracking_margin_m
        return traj, ends, radius

    def _plan(self, cap: float) -> tuple[ShieldedTrajectory, np.ndarray, np.ndarray]:
        """:meth:`_shielded` with the follower's path speed capped at ``cap`` (rad/s)."""
        f = self.follower
        old = f.speed_cap
        f.speed_cap = cap
        try:
            return self._shielded()
        finally:
            f.speed_cap = old

    def _plan_and_verify(
        self, hum: Humans | None
    ) -> tuple[ShieldedTrajectory, np.ndarray, np.ndarray, bool]:
        """Plan and verify one shielded trajectory (SSM) with speed scaling
        (:class:`~sara_app.safety.settings.SsmSettings`): a check that fails at full path speed is
        planned again at a lower path-speed cap and checked again. Only a verified trajectory is
        committed, as without scaling. ``self._res`` keeps the last check's details. One
        compiled call (:mod:`~sara_app.safety.ssm_cycle_kernels`) where it can; the Python
        composition of the same kernels (:meth:`_composed`) where it declines, where nobody is
        in the cell, the follower has nothing ahead or the check uses the arm model."""
        f = self.follower
        check = self.verifier.kernel_inputs()  # in the verifier's current model order
        if hum is None or self._compiled is None or check is None:
            return self._composed(hum)
        state = f.kernel_state(self.settings.dt_s)
        if state is None:
            return self._composed(hum)
        sc = self.settings.ssm
        V_here = f.admissible_here()[0]
        human = self.verifier.human(*hum)
        sampling, occupancy = self._compiled
        constants, codes, maps, arm = check
        info = self._info
        code, pts, joint, bounds, ends, radius, free, evaluated, closest, parts = _SSM_CYCLE(
            *state, sampling, occupancy, human, constants, codes, maps, arm,
            (f.speed_cap, sc.min_speed_scale * V_here, sc.cut), sc.max_replans,
            self._distance[self._want_distance], info, self._peek_record,
        )  # fmt: skip
        if code != DONE:
            return self._composed(hum)
        K = parts.shape[1]
        step = f.step_from_record(self._peek_record, int(info[3]), self.settings.dt_s)
        samples = (pts[0], (pts[1], pts[2], pts[3]), joint[0], joint[1], joint[3], joint[4],
                   bounds[0], bounds[1], pts[4, :K])  # fmt: skip
        traj = from_samples(step, samples)
        self._scale = min(1.0, float(info[1]) / V_here) if V_here > 0 else 1.0
        self._res = res = SsmResult(
            bool(info[0]), free, evaluated, closest, parts, self.verifier.order
        )
        self._promote(res, int(info[4]))
        if self._distance[self._want_distance][0]:  # the kernel computed it
            self._separation = float(info[5])
        return traj, ends, radius, res.safe

    def _composed(
        self, hum: Humans | None
    ) -> tuple[ShieldedTrajectory, np.ndarray, np.ndarray, bool]:
        """:meth:`_plan_and_verify` by the Python composition of the kernels."""
        self._scale = 1.0
        traj, ends, radius = self._shielded()
        if hum is None:  # nobody in the cell
            return traj, ends, radius, True
        sc = self.settings.ssm
        y, v, dv, age, widen, caps = hum
        res = self.verifier.verify(y, v, dv, age, traj.times, ends, radius, widen, caps)
        if not res.safe and sc.max_replans:
            V_here = self.follower.admissible_here()[0]
            c_min = sc.min_speed_scale * V_here
            cap = math.inf
            for _ in range(sc.max_replans):
                cand = sc.cut * min(cap, float(traj.sd.max()))
                if res.safe or not cand >= c_min:  # NaN too
                    break
                cap = cand
                traj, ends, radius = self._plan(cap)
                res = self.verifier.verify(y, v, dv, age, traj.times, ends, radius, widen, caps)
            self._scale = min(1.0, cap / V_here) if V_here > 0 else 1.0
        self._res = res
        done = np.flatnonzero(res.evaluated.any(axis=(0, 2)))
        self._promote(res, int(done[-1]) if done.size else -1)
        return traj, ends, radius, res.safe

    def _promote(self, res: SsmResult, last: int) -> None:
        """After a successful check, the model that completed it (``last``: its index along
        the result's model axis, the last one evaluated) goes first in the next check."""
        if res.safe and last > 0 and res.models is not None:
            self.verifier.promote(res.models[last])

    def _annotate(self, out: CycleResult, res: Any) -> None:
        """Mode-specific details of the cycle result (SSM: per-model verdicts)."""
        if not isinstance(res, SsmResult):
            return
        out.ssm = res
        out.speed_scale = self._scale
        out.intervened = out.intervened or self._scale < 1.0
        # per model, over people and intervals (the check's arrays: (H, M, K) booleans)
        flags = self._verdicts
        if res.evaluated.shape[1] != flags.shape[1] or res.free.shape != res.evaluated.shape:
            raise InputError(
                f"check arrays {res.evaluated.shape} and {res.free.shape}; expected (H, "
                f"{flags.shape[1]}, K) both"
            )
        _MODEL_VERDICTS(res.evaluated, res.free, flags)
        evaluated, free = flags.tolist()
        models = self.verifier.models if res.models is None else res.models
        for name, ev, fr in zip(models, evaluated, free):
            if ev:
                out.model_free[name] = fr

    def min_distance(self, q: np.ndarray, ys: list[np.ndarray]) -> float:
        """Smallest surface distance (m) between the robot's link capsules at ``q (n,)`` and
        the measured body parts (half thickness) of people with joints ``ys``, each ``(J,
        3)`` (one compiled call, :mod:`~sara_app.safety.distance_kernels`); ``inf`` without
        people, NaN when a distance is."""
        if not ys:
            return math.inf
        J, n = self.reach.skeleton.n_joints, self.robot.n_dof
        q = as_f8(q)
        Y = as_f8(ys[0])[None] if len(ys) == 1 else np.stack([as_f8(y) for y in ys])
        half = as_f8(self._half_th)
        if q.shape != (n,) or Y.shape[1:] != (J, 3) or half.shape != (len(self._parts),):
            raise InputError(
                f"q {q.shape}, joints {Y.shape[1:]} and half thicknesses {half.shape}; "
                f"expected ({n},), ({J}, 3) and ({len(self._parts)},)"
            )
        q_index, N, parents, link_joint, ends_joint, H, E, Q, radius = self._distance_inputs
        return float(
            _MIN_DISTANCE(q, q_index, N, parents, H, link_joint, ends_joint, E, Q, radius, Y,
                          self._parts, half)
        )  # fmt: skip


_HUMAN_VALUES = entry(human_values)
"""Without numba's dispatcher: ``Shield._check_humans`` checks the shapes, ``as_f8`` the
dtypes."""
_MIN_DISTANCE = entry(min_distance_kernel)
"""Without numba's dispatcher: :meth:`Shield.min_distance` checks its arguments' shapes and
dtypes (the kernel indexes the joints by ``part_joints`` without bounds checks)."""
_MODEL_VERDICTS = entry(model_verdicts)
"""Without numba's dispatcher: :meth:`Shield._annotate` checks the shapes; the check's arrays
are booleans (its own kernels' or the verifier's)."""
_SSM_CYCLE = entry(ssm_cycle_kernel)
"""The kernel without numba's dispatcher (typing its nested tuples took about 5 us per call):
its inputs are the verifier's checked arrays and the shield's own (see :func:`entry`)."""


def _distance_inputs(occupancy: RobotOccupancy, radius_m: np.ndarray) -> tuple[np.ndarray, ...]:
    """:func:`~sara_app.safety.distance_kernels.min_distance_kernel`'s kinematics constants,
    its scratch and the links' radii: ``(q_index, N, parents, link_joint, ends_joint, H, E, Q,
    radius_m)``."""
    q_index, N, parents, link_joint, ends_joint, _axes, T0 = occupancy.kernel_arrays()
    n, L = len(q_index), len(link_joint)
    H = np.zeros((1, n + 1, 4, 4))
    H[:, :, 3, 3] = 1.0
    H[0, 0] = T0
    return (q_index, N, parents, link_joint, ends_joint, H, np.empty((1, L, 2, 3)),
            np.empty((1, n)), np.array(radius_m, dtype=np.float64))  # fmt: skip


def _compiled_inputs(
    verifier: SsmVerifier, occupancy: RobotOccupancy, margin_m: np.ndarray, max_interval_s: float
) -> tuple[tuple[float, float], tuple[np.ndarray, ...]] | None:
    """What :func:`~sara_app.safety.ssm_cycle_kernels.ssm_cycle_kernel` needs besides the
    follower, the people and the check (``SsmVerifier.kernel_inputs``, in its current model
    order): ``(sampling, occupancy)``; None where it cannot run (the arm model)."""
    if verifier.kernel_inputs() is None:
        return None
    return (float(BOUND_PAD), float(max_interval_s)), occupancy.plan_arrays(margin_m)
