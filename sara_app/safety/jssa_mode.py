"""JSSA as a safety mode of the cell (Liu et al. 2022): the :class:`Shield` interface around a
jerk-level tracking controller whose jerk :class:`~sara_app.safety.jssa.JssaController` filters.

Per cycle (``dt = settings.dt_s``):

1. checks as in SSM: measured robot state against the commanded one, skeletons present, finite,
   fresh, not from the future; any fault brakes (:func:`~sara_app.safety.jssa_qp.brake_jerk`
   within the jerk bounds), mode ``"fault"``;
2. the reference (the :class:`PathFollower` of the task, :attr:`follower`) advances one step;
   the nominal jerk tracks it (:func:`tracking_jerk`);
3. the humans' body-part capsules (measured joints, half thickness of the parameter set) are
   moved to the present with their measured velocities (constant velocity, eq. 4: the skeleton
   stamped ``s`` shows the pose at ``s - delay``, so it is extrapolated over
   ``t_now - s + delay``), and carry those velocities at their ends (the velocity error
   bound ``dv`` is not used: JSSA has no set-valued human model);
4. JSSA projects the nominal jerk (eq. 13-14) and the robot state integrates it (eq. 1).

Reference. The follower advances along its intended, jerk-limited path motion at a path speed
governed by the tracking error ``e`` (largest joint error): no cap while ``e <=
RESUME_ERROR_RAD``, then a cap (:attr:`PathFollower.speed_cap`, set for the step and restored
after it) falling linearly from the path's top admissible speed to 0 at ``HOLD_ERROR_RAD``. When
JSSA holds the robot back or pushes it aside, the reference slows down within its own
acceleration and jerk limits and waits, and it speeds up again as the robot catches up: it
settles where its speed matches the progress JSSA allows. Without this the reference would run
ahead while a person blocks the robot, and once released the tracking law would chase it with
saturated jerks, overshooting (the paper replans its buffer for the same reason, Sec. 3.3).

Tracking law: linear with a triple pole (critically damped, no overshoot while unsaturated);
far from the reference the position error is scaled down to ``TRACK_CLIP_RAD`` (the robot then
approaches at about ``omega * TRACK_CLIP_RAD / 3`` rad/s instead of saturating the jerk box,
where a linear law on a triple integrator can oscillate).

Rest. When the reference stands still and the robot is within ``SETTLE_*`` of it, the robot's
state is set to the reference exactly (a jump of at most 1e-5 rad, 1e-4 rad/s, 1e-3 rad/s^2, far
below any controller's tracking error): the exponential tracking would otherwise never end, and
a settled robot is what :meth:`Shield.adopt` needs to hand the robot to another mode on its path.

Static obstacles. The environment boxes are NOT given to JSSA. They are part of the task, which
is planned against them (the SSM and PFL shields do not check them either), and in every shipped
scenario the path passes 0.066 m above the table, within ``d_min`` plus any capsule cover of the
box: in ``single`` mode the table would be the critical pair in most cycles and hide the person
(the paper's sparse-obstacle assumption, Sec. 3.1), and JSSA would bend the task off its path.

The guarantee differs from SSM and PFL. JSSA keeps its index ``phi <= 0``, which is meant to
keep ``d >= d_min`` while every person moves at constant velocity (eq. 4), up to the
linearisation of eq. 13 and the continuous-to-discrete gap the paper leaves open. There is no
verified failsafe and no reachable-set over-approximation: a person who accelerates toward the
robot (every real motion does) can get closer than ``d_min``, and contact with a moving robot is
possible. Even at constant velocity ``d >= d_min`` is not guaranteed: ``phi <= 0`` implies it
only for states reachable from rest (the paper's ``X_S*``), and with one constraint (the
paper's ``single``) a second pair that closes in fast is unconstrained until it becomes the
closest (tests/test_jssa_mode.py shows a crossing where that ends below ``d_min``; ``multi``, one
constraint per pair, kept ``d_min`` in the randomised crossings tried). Faults brake, but the
brake itself is not checked against the people.
"""

from __future__ import annotations

import math
import time

import numpy as np

from sara_app.errors import SaraError
from sara_app.human.reach import MODELS, HumanReach
from sara_app.robot.deviation_kernels import max_abs, max_abs_diff
from sara_app.robot.model import RobotModel
from sara_app.robot.trajectory import JointState, PathFollower
from sara_app.safety.jssa import JssaController, JssaParams, JssaResult, integrate
from sara_app.safety.settings import JssaSettings, ShieldSettings
from sara_app.safety.shield import CycleResult, HumanState, Shield

TRACK_OMEGA_PER_S = 20.0
"""Pole (rad/s, triple) of the jerk tracking law."""
TRACK_CLIP_RAD = 0.04
"""Position errors are scaled down to this largest joint error before the tracking law."""
HOLD_ERROR_RAD = 0.02
"""Largest joint tracking error at which the reference's speed cap reaches 0 (rad)."""
RESUME_ERROR_RAD = 0.005
"""Largest joint tracking error up to which the reference runs uncapped (rad)."""
GOAL_Q_RAD, GOAL_V_RAD_S = 1e-3, 1e-2
"""Convergence to the end of the reference that counts as the task (pass) done."""
SETTLE_Q_RAD, SETTLE_V_RAD_S, SETTLE_A_RAD_S2 = 1e-5, 1e-4, 1e-3
"""How close to a resting reference the robot is set onto it; ``at_rest`` uses the last two."""


def tracking_jerk(
    state: tuple[np.ndarray, np.ndarray, np.ndarray],
    ref: JointState,
    ref_next: JointState,
    dt: float,
    omega: float = TRACK_OMEGA_PER_S,
) -> np.ndarray:
    """Nominal jerk ``(n,)``: the reference's mean jerk over the step (feed-forward, exact for
    the acceleration) plus ``-(w^3 e_q + 3 w^2 e_v + 3 w e_a)`` on the error to ``ref`` (now)."""
    q, v, a = state
    u_ff = (ref_next.a - ref.a) / dt
    w = omega
    e_q = q - ref.q
    big = max_abs(e_q)
    if big > TRACK_CLIP_RAD:  # far away: approach at about w * clip / 3 rad/s (see above)
        e_q = e_q * (TRACK_CLIP_RAD / big)
    return u_ff - (w**3 * e_q + 3.0 * w * w * (v - ref.v) + 3.0 * w * (a - ref.a))


def reference_cap(err_rad: float, follower: PathFollower) -> float:
    """Path-speed cap (rad/s) of the reference for a tracking error ``err_rad``: ``inf`` up to
    ``RESUME_ERROR_RAD``, then linear from the path's top admissible speed to 0 at
    ``HOLD_ERROR_RAD``."""
    if err_rad <= RESUME_ERROR_RAD:
        return math.inf
    V = follower.admissible_speed[1]
    top = float(V.max()) if V.size else 0.0
    return top * max(0.0, (HOLD_ERROR_RAD - err_rad) / (HOLD_ERROR_RAD - RESUME_ERROR_RAD))


def jssa_params(spec: JssaSettings) -> JssaParams:
    """The controller's parameters from the scenario's JSSA section, with the sliding-point
    correction of ``d''`` on (see :mod:`sara_app.safety.jssa_index`)."""
    return JssaParams(
        d_min_m=spec.d_min_m,
        lambda_1=spec.lambda_1,
        lambda_2=spec.lambda_2,
        mode=spec.constraints,
        eta_per_s=spec.eta_per_s,
        sliding=True,
    )


class JssaMode(Shield):
    """JSSA behind the :class:`Shield` interface. ``follower`` is the reference (the task);
    :attr:`robot_state` the integrated robot. ``boxes`` ``(T_world_box (B, 4, 4),
    half_extents_m (B, 3))`` are kept (:attr:`boxes`) but not avoided (see the module notes).
    ``verified`` in a :class:`CycleResult` means: no fault and no fallback brake, i.e. the JSSA
    constraint was met under its own assumptions; it is not a verification."""

    safety_mode = "jssa"
    holds_failsafe = False

    def __init__(
        self,
        robot: RobotModel,
        follower: PathFollower,
        reach: HumanReach,
        settings: ShieldSettings | None = None,
        spec: JssaSettings | None = None,
        boxes: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        super().__init__(robot, follower, reach, settings)
        self.spec = spec or JssaSettings()
        self.controller = JssaController(robot, jssa_params(self.spec), follower.limits)
        self.boxes = boxes
        self._delay_s = float(reach.params.delay_s)
        self.halt_reason: str | None = None
        """Set: every cycle brakes (JSSA holds no verified failsafe, so a switch to another
        safety mode waits for the robot at rest; the worker halts it for such a switch)."""
        st = follower.state
        self._q, self._v, self._a = st.q.copy(), st.v.copy(), st.a.copy()
        self.last: JssaResult | None = None

    # -- state ----------------------------------------------------------------------------------

    @property
    def robot_state(self) -> JointState:
        return JointState(self._q.copy(), self._v.copy(), self._a.copy())

    @property
    def at_rest(self) -> bool:
        return bool(max_abs(self._v) <= SETTLE_V_RAD_S and max_abs(self._a) <= SETTLE_A_RAD_S2)

    def restart_from(self, q: np.ndarray, waypoints: np.ndarray | None = None) -> None:
        """The measured robot rests at ``q``: the reference (through the waypoints ahead, as
        :meth:`Shield.restart_from`) and the robot state restart there. Raises
        :class:`ParameterError` unless at rest."""
        super().restart_from(q, waypoints)
        self._q = np.asarray(q, dtype=float).copy()
        self._v, self._a = np.zeros_like(self._q), np.zeros_like(self._q)

    @property
    def task_done(self) -> bool:
        """The reference is done and the robot has converged to its end: within ``GOAL_Q_RAD``
        and ``GOAL_V_RAD_S`` per joint (the next pass may start; the robot keeps settling)."""
        f = self.follower
        return (
            f.done
            and max_abs_diff(self._q, f.state.q) <= GOAL_Q_RAD
            and max_abs(self._v) <= GOAL_V_RAD_S
        )

    def adopt(self, previous: Shield) -> None:
        """Take over the previous layer's follower as the reference and its commanded state as
        the robot's (always possible: JSSA starts from any state)."""
        self.follower = previous.follower
        st = previous.robot_state
        self._q, self._v, self._a = (np.array(x, dtype=float) for x in (st.q, st.v, st.a))

    def brake_step(self) -> JointState:
        dt = self.settings.dt_s
        res = self.controller.brake(self._v, self._a, "brake step")
        self._advance(res.jerk, dt)
        try:
            self.follower.brake(dt)
        except SaraError:
            pass
        return self.robot_state

    # -- parts of a cycle -----------------------------------------------------------------------

    def _commanded_q(self) -> np.ndarray:
        return self._q  # the robot follows JSSA's integrated state, not the path

    def _nominal(self, dt: float) -> np.ndarray:
        """Advance the reference one step at the governed speed (see the module notes) and
        return the nominal jerk ``(n,)`` that tracks it."""
        f = self.follower
        ref = f.state
        err = max_abs_diff(self._q, ref.q)
        cap = reference_cap(err, f)
        outer = f.speed_cap
        f.speed_cap = min(outer, cap)
        try:
            ref_next = f.step(dt)
        finally:
            f.speed_cap = outer
        return tracking_jerk((self._q, self._v, self._a), ref, ref_next, dt)

    def human_capsules(
        self, t_now: float, humans: list[HumanState], usable: list[int]
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Body-part capsules of the usable humans at ``t_now`` under constant velocity:
        ends ``(H P, 2, 3)``, radii ``(H P,)``, end velocities ``(H P, 2, 3)``."""
        parts = self._parts
        if not usable:
            return np.zeros((0, 2, 3)), np.zeros(0), np.zeros((0, 2, 3))
        y = np.stack([humans[i].y for i in usable])  # (H, J, 3)
        v = np.stack([humans[i].v for i in usable])
        lead = np.array([t_now - float(humans[i].stamp_s or 0.0) for i in usable])
        y = y + v * (np.maximum(lead, 0.0) + self._delay_s)[:, None, None]
        radius = np.tile(self._half_th, len(usable))
        vel = MODELS.index("vel")
        for k, i in enumerate(usable):  # a person measured less precisely: wider capsules
            w = humans[i].widen_m
            if w is not None:
                radius[k * len(parts) : (k + 1) * len(parts)] += w[vel]
        return y[:, parts].reshape(-1, 2, 3), radius, v[:, parts].reshape(-1, 2, 3)

    def _advance(self, u: np.ndarray, dt: float) -> None:
        self._q, self._v, self._a = integrate(self._q, self._v, self._a, u, dt)

    def _settle(self) -> None:
        f = self.follower
        if f.sd > 1e-9 or abs(f.sdd) > 1e-7:
            return
        ref = f.state
        if (
            max_abs_diff(self._q, ref.q) <= SETTLE_Q_RAD
            and max_abs(self._v) <= SETTLE_V_RAD_S
            and max_abs(self._a) <= SETTLE_A_RAD_S2
        ):
            self._q, self._v, self._a = ref.q.copy(), np.zeros_like(self._v), np.zeros_like(self._a)

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
        """One JSSA cycle at cell time ``t_now``: the robot state advances by ``dt_s``."""
        t0 = time.perf_counter()
        dt = self.settings.dt_s
        faults: list[str] = list(input_faults or ())  # the cell's inputs (trackers, robot)
        ages: dict[str, float] = {}
        self._check_tracking(measured, faults)
        usable = self._check_humans(t_now, humans, faults, ages)
        res: JssaResult | None = None
        if not faults and self.halt_reason is None:  # halted: asked to stop (leaving JSSA)
            try:
                u_nom = self._nominal(dt)
                ends, radius, vel = self.human_capsules(t_now, humans, usable)
                res = self.controller.step(self._q, self._v, self._a, u_nom, ends, radius, vel, dt)
            except SaraError as e:  # a reference failure is a fault, never a crash
                faults.append(f"cycle failed: {e}")
        if res is None or faults:
            why = "; ".join(faults) or self.halt_reason or ""
            res = self.controller.brake(self._v, self._a, why)
            try:
                self.follower.brake(dt)  # the reference waits on its failsafe
            except SaraError:
                pass
        self._advance(res.jerk, dt)
        self._settle()
        self.last = res
        if faults:
            mode = "fault"
        elif res.fallback:
            mode = "failsafe"
        elif self.at_rest:
            mode = "rest"
        else:
            mode = "intended"
        self._count(mode)
        command = self.robot_state
        out = CycleResult(
            t_s=t_now,
            mode=mode,
            verified=not faults and not res.fallback,
            command=command,
            faults=faults,
            ages_s=ages,
            safety_mode=self.safety_mode,
        )
        out.jssa = res
        out.intervened = bool(res.active or res.fallback)
        if want_distance and usable:
            out.min_distance_m = self.min_distance(command.q, [humans[i].y for i in usable])
        out.cycle_time_us = (time.perf_counter() - t0) * 1e6
        return out
