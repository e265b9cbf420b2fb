"""Online path following. :class:`PathFollower` plans the scalar path motion online with
piecewise-constant path jerk. Every step it aims for the admissible speed of the current piece with
the time-optimal jerk-limited velocity profile (limits: the smallest box over a look-ahead window
that covers any stopping distance), and starts braking, at the exact instant inside the step, when a
time-optimal brake from the end of the step would no longer reach the lower admissible speed of an
upcoming piece before that piece, or standstill at the end of the path. A step is committed only
when the joint limits provably hold over it and a path-consistent failsafe stop
(the compiled planner, :mod:`sara_app.robot.planning_kernels`) exists from its end; otherwise the
follower executes the failsafe it already holds (recursive feasibility: the tail of a valid stop is
a valid stop). A ``speed_cap`` (path speed, default inf; set by the PFL shield for speed scaling)
lowers every admissible speed the follower aims for to at most the cap: the same planning, slower
targets.

Fallback steps (counted in ``fallback_steps``) do not happen on a path followed from rest to
rest; after a replan they can (for instance when the new goal forces the robot to stop where the
failsafe it holds stops): the robot then brakes along that failsafe, which is always valid.

Replanning (:meth:`PathFollower.replan`) never forces a stop of a moving robot. The new path
keeps the current path's geometry up to the end of the failsafe held (pushed on to the end of a
blend if it ends inside one), so that failsafe remains valid on the new path; from there it runs
straight on in the current direction (at most ``blend_distance``, at most half way to the first
new waypoint, inside the joint position box) to a new corner, blended like any other, and on
through the new waypoints. If the follower could not slow down to the new corner's admissible
speed before it, the corner is moved further along the straight line. Position, velocity and
acceleration are continuous because the geometry around the robot does not change. Special
cases: at rest the new path starts at the current position; a request equal to the previous one
(or a single goal equal to the current end) changes nothing; if the robot is already braking to
a standstill within ``blend_distance`` of the current end, or a joint limit leaves no room to go
on straight, the current path is finished first and the new one starts from rest.

The path geometry and its admissible path-speed boxes are in :mod:`sara_app.robot.path`, the
scalar jerk-limited profiles in :mod:`sara_app.robot.profile`. A step is planned in one compiled
call (:mod:`sara_app.robot.planning_kernels`); its Python reference, equal bit for bit, lives in
``tests/planning_reference.py``.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from sara_app.errors import RobotModelError
from sara_app.robot.joints import (
    LIMIT_MARGIN,
    REST_A,
    REST_V,
    S_TOL,
    JointState,
    check_waypoints,
    limit_arrays,
)
from sara_app.robot.model import JointLimits
from sara_app.robot.path import PathTrajectory
from sara_app.robot.path_limits import PathTables, path_tables, piece_boxes
from sara_app.robot.planning_kernels import (
    FALLBACK,
    H_CAP,
    O_END,
    O_HEAD,
    O_LIM,
    O_STOP,
    OUT_LEN,
    PC_COLS,
    S_CAP,
    STEP_REST,
    peek_kernel,
    profile_record,
    record_start,
)
from sara_app.robot.profile import (
    ScalarProfile,
    cut_phases,
    phases_end,
    velocity_phases,
)

if TYPE_CHECKING:
    from sara_app.robot.failsafe import StopProfile

_CONSTS = np.array([S_TOL, REST_V, REST_A, LIMIT_MARGIN, 2.0, 3.0])
"""The constants :func:`~sara_app.robot.planning_kernels.peek_kernel` reads (in the order of its
``C_*`` indices; the exponents at run time, see that module)."""
_CONSTS.flags.writeable = False

__all__ = ["FollowerStep", "JointState", "PathFollower", "PathTrajectory", "time_scaling"]


class FollowerStep:
    """One planned control step of a :class:`PathFollower` (nothing mutated until committed).

    ``start``: ``(s, s', s'')`` it was planned from; ``profile``: the path motion ``s(t)`` over
    ``[0, dt]`` from there; ``end``: ``(s, s', s'')`` at ``dt``; ``stop``: the failsafe from
    ``end`` (valid); ``fallback``: True when the intended motion could not be verified and the
    step is the first ``dt`` of the failsafe the follower already held.

    A step read from the planning kernel's record (:meth:`PathFollower.step_from_record`) makes
    its ``profile`` and ``stop`` objects on first use: a control cycle reads neither when it
    commits a verified step (the next cycle plans from ``end``; the stop is needed only when a
    later cycle falls back or brakes), and making them took about 3.5 us of the SSM cycle's 45.
    """

    __slots__ = ("dt", "path", "start", "end", "fallback", "_profile", "_stop", "_record")

    def __init__(
        self,
        dt: float,
        path: PathTrajectory,
        profile: ScalarProfile,
        end: tuple[float, float, float],
        stop: StopProfile,
        fallback: bool,
    ) -> None:
        self.dt, self.path, self.start, self.end = dt, path, profile.start, end
        self.fallback = fallback
        self._profile: ScalarProfile | None = profile
        self._stop: StopProfile | None = stop
        self._record: tuple[list[float], int] | None = None

    @classmethod
    def recorded(
        cls,
        dt: float,
        path: PathTrajectory,
        start: tuple[float, float, float],
        record: list[float],
        status: int,
    ) -> FollowerStep:
        """The intended step of ``peek_kernel``'s record (a list, the caller's copy) and
        status ``STEP`` or ``STEP_REST``; ``start``: the record's own (its head profile's
        first break, :func:`~sara_app.robot.planning_kernels.record_start`), what
        :meth:`PathFollower.commit` checks against the follower's state."""
        step = cls.__new__(cls)
        step.dt, step.path, step.start, step.fallback = dt, path, start, False
        step.end = (record[O_END], record[O_END + 1], record[O_END + 2])
        step._profile = step._stop = None
        step._record = (record, status)
        return step

    @property
    def profile(self) -> ScalarProfile:
        if self._profile is None:
            self._from_record()
        return self._profile  # type: ignore[return-value]  # made above

    @property
    def stop(self) -> StopProfile:
        if self._stop is None:
            self._from_record()
        return self._stop  # type: ignore[return-value]  # made above

    def _from_record(self) -> None:
        from sara_app.robot.failsafe import StopProfile, rest_stop

        if self._record is None:
            raise RobotModelError("a follower step has neither its profiles nor their record")
        o, status = self._record
        self._profile = ScalarProfile._from_breaks(*profile_record(o, O_HEAD, H_CAP))
        stop_prof = ScalarProfile._from_breaks(*profile_record(o, O_STOP, S_CAP))
        if status == STEP_REST:
            self._stop = rest_stop(self.path, stop_prof.start[0])
        else:
            self._stop = StopProfile(self.path, stop_prof, o[O_LIM], o[O_LIM + 1])


class PathFollower:
    """Online jerk-limited follower of a :class:`PathTrajectory` under :class:`JointLimits`.

    ``path_or_waypoints``: a path, or waypoints ``(W, n)`` to build one. The follower starts at
    rest at ``s = 0``. ``s``, ``sd`` (s'), ``sdd`` (s'') expose the path state; ``state`` the
    joint state; ``stop`` the failsafe the follower currently holds (a valid path-consistent
    stop from the current state). See the module notes for the planning scheme.
    """

    _held: StopProfile | FollowerStep

    def __init__(
        self,
        path_or_waypoints: PathTrajectory | object,
        limits: JointLimits,
        *,
        blend_distance: float = 0.1,
        tangential_share: float = 0.5,
    ) -> None:
        from sara_app.robot.failsafe import rest_stop

        self._rest_stop = rest_stop
        if not (0.0 < tangential_share < 1.0):
            raise RobotModelError(
                f"tangential_share = {tangential_share!r}; expected a fraction in (0, 1)"
            )
        self.limits = limits
        self.tangential_share = float(tangential_share)
        if isinstance(path_or_waypoints, PathTrajectory):
            path = path_or_waypoints
            n = path.n_joints
            lim = limit_arrays(limits, n)
            check_waypoints(path.waypoints, limits, n)
            self.blend_distance = path.blend_distance
        else:
            path = PathTrajectory(path_or_waypoints, blend_distance=blend_distance, limits=limits)
            lim = limit_arrays(limits, path.n_joints)
            self.blend_distance = float(blend_distance)
        self._lim = lim
        self._t = 0.0
        self._cap = math.inf
        self.fallback_steps = 0
        self._pending: np.ndarray | None = None
        self._goal: np.ndarray | None = None
        self._set_path(path, 0.0, 0.0, 0.0, None)

    # -- state ---------------------------------------------------------------------------------

    def _set_path(
        self, path: PathTrajectory, s: float, v: float, a: float, stop: StopProfile | None
    ) -> None:
        self.path = path
        self._S = path.length
        self._s, self._v, self._a = s, v, a
        # per-path constants of the planning hot path
        self._n_pieces = path.n_pieces
        self._starts = path._s0_list
        self._tab: PathTables = path_tables(path, self.limits)
        if path.n_pieces:
            V, A, J = piece_boxes(path, self._lim, self.tangential_share)
            self._V = [float(x) for x in V]
            self._A = [float(x) for x in A]
            self._J = [float(x) for x in J]
            self._A_min = min(self._A)
            self._A_top = max(self._A)
            self._J_min = min(self._J)
            self._ramp_c = 2.0 * self._A_top / self._J_min  # of the look-ahead in _intended
            # smallest box from each piece to the end of the path
            self._A_tail = np.minimum.accumulate(A[::-1])[::-1].tolist()
            self._J_tail = np.minimum.accumulate(J[::-1])[::-1].tolist()
            self._ktab = self._kernel_tables()
        else:
            self._V, self._A, self._J = [], [], []
        self._stop = stop if stop is not None else self._rest_stop(path, s)

    def _kernel_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The path as :func:`~sara_app.robot.planning_kernels.peek_kernel` reads it: per piece
        ``pc (P, PC_COLS)`` (start, boxes, tail boxes, straight-piece limits, blend
        parameters), ``rows (P, n, 7)`` (the stop tables' per-joint rows) and ``geo (P, 2, n)``
        (``u``, ``dl``); the values of the lists the Python methods read."""
        path, tab = self.path, self._tab
        p = path._p
        if p is None:
            raise RobotModelError("a path of one point has no pieces")
        pc = np.empty((path.n_pieces, PC_COLS))
        cols = (
            path._s0_list, self._V, self._A, self._J, self._A_tail, self._J_tail, tab.lin,
            tab.v_lin, tab.a_lin, tab.j_lin, path._x0_list, path._x1_list, path._invL_list,
        )  # fmt: skip
        for i, col in enumerate(cols):
            pc[:, i] = col
        rows = np.array(tab.rows, dtype=float).reshape(path.n_pieces, path.n_joints, 7)
        geo = np.ascontiguousarray(np.stack([p.u, p.dl], axis=1), dtype=float)
        for arr in (pc, rows, geo):
            arr.flags.writeable = False
        return pc, rows, geo

    @property
    def s(self) -> float:
        """Path coordinate (rad)."""
        return self._s

    @property
    def sd(self) -> float:
        """Path speed s' (rad/s)."""
        return self._v

    @property
    def sdd(self) -> float:
        """Path acceleration s'' (rad/s^2)."""
        return self._a

    @property
    def t(self) -> float:
        """Time followed so far (s)."""
        return self._t

    @property
    def stop(self) -> StopProfile:
        """The failsafe held for the current state (valid, path-consistent)."""
        return self._stop

    @property
    def _stop(self) -> StopProfile:
        """The failsafe held: a stop, or the committed step whose stop it is (made here)."""
        held: StopProfile | FollowerStep = self._held
        if isinstance(held, FollowerStep):
            held = self._held = held.stop
        return held

    @_stop.setter
    def _stop(self, stop: StopProfile) -> None:
        self._held = stop

    @property
    def speed_cap(self) -> float:
        """Upper bound on the path speed s' the intended motion aims for (rad/s; default inf).

        The intended motion targets ``min(V_k, speed_cap)`` on the current and every upcoming
        piece ``k`` (``V_k``: the piece's admissible speed), so below the current speed it
        decelerates within the path's acceleration and jerk boxes; every step is still checked
        against the joint limits and ends with a valid failsafe, whatever the cap. It steers
        planning only: the failsafe held is never changed. 0 brings the robot to rest along the
        intended motion (not ``done``: raising the cap resumes)."""
        return self._cap

    @speed_cap.setter
    def speed_cap(self, cap: float) -> None:
        if type(cap) is float and cap >= 0.0:  # the common case, as below
            self._cap = cap
            return
        try:
            c = float(cap)
        except (TypeError, ValueError):
            c = math.nan
        if not c >= 0.0:  # NaN too
            raise RobotModelError(f"speed_cap = {cap!r} rad/s; expected a path speed >= 0 or inf")
        self._cap = c

    @property
    def admissible_speed(self) -> tuple[np.ndarray, np.ndarray]:
        """``(piece starts, V)``: the precomputed admissible path speed, piecewise constant."""
        return self.path.piece_starts, np.array(self._V)

    def admissible_here(self) -> tuple[float, float]:
        """``(V at the current s, largest V of the path)`` (rad/s; 0 for a path without
        pieces): :attr:`admissible_speed` without its array copy."""
        V = self._V
        if not V:
            return 0.0, 0.0
        return V[self.path.piece_index(self._s)], max(V)

    @property
    def done(self) -> bool:
        """At rest at the end of the path."""
        return self._S - self._s <= S_TOL and self._v <= REST_V and abs(self._a) <= REST_A

    @property
    def state(self) -> JointState:
        q, dq, d2q = self.path.derivatives(self._s, 2)
        v = dq * self._v
        return JointState(q=q, v=v, a=d2q * self._v**2 + dq * self._a)

    def copy(self) -> PathFollower:
        other = PathFollower.__new__(PathFollower)
        other.__dict__.update(self.__dict__)
        return other

    # -- planning ------------------------------------------------------------------------------

    def _path_s0(self, k: int) -> float:
        return self.path._s0_list[k]

    def peek(self, dt: float) -> FollowerStep:
        """Plan one control step of ``dt`` seconds without changing the follower, by
        :func:`~sara_app.robot.planning_kernels.peek_kernel` (``tests/planning_reference.py``
        is its independent Python reference)."""
        if not (type(dt) is float and 0.0 < dt < math.inf):  # else the full check
            if not (isinstance(dt, int | float) and math.isfinite(dt) and dt > 0):
                raise RobotModelError(f"dt = {dt!r} s; expected a finite time step > 0")
            dt = float(dt)
        s = self._s
        if (self._S - s <= S_TOL and self._v <= REST_V and abs(self._a) <= REST_A) or (
            self._n_pieces == 0
        ):
            prof = ScalarProfile(s, 0.0, 0.0, [dt], [0.0])  # done (at rest at the end)
            return FollowerStep(dt, self.path, prof, (s, 0.0, 0.0), self._stop, False)
        return self._peek_compiled(dt)

    def _peek_compiled(self, dt: float) -> FollowerStep:
        """:meth:`peek` of a follower that is not done, planned by the compiled kernel."""
        s, v, a = self._s, self._v, self._a
        out = np.empty(OUT_LEN)
        status = peek_kernel(
            s, v, a, dt, self._cap, self._S, self._A_min, self._J_min, self._ramp_c,
            *self._ktab, _CONSTS, out,
        )  # fmt: skip
        return self.step_from_record(out, status, dt)

    def kernel_state(
        self, dt: float
    ) -> tuple[tuple[float, ...], tuple[np.ndarray, ...], tuple[np.ndarray, ...]] | None:
        """What a compiled caller of :func:`~sara_app.robot.planning_kernels.peek_kernel` and
        :func:`~sara_app.robot.trajectory_kernels.shielded_samples_kernel` needs to plan this
        follower's next step of ``dt`` at any cap: ``((s, s', s'', dt, S, A_min, J_min,
        ramp_c), (pc, rows, geo, consts), path piece tables)``; None when :meth:`peek` would
        not call the kernel (done, or a path without pieces)."""
        if self.done or self._n_pieces == 0:
            return None
        s, v, a, S = self._s, self._v, self._a, self._S
        follower = (s, v, a, float(dt), S, self._A_min, self._J_min, self._ramp_c)
        return follower, (*self._ktab, _CONSTS), self.path.piece_tables

    def step_from_record(self, out: np.ndarray, status: int, dt: float) -> FollowerStep:
        """The step of :meth:`peek` from ``peek_kernel``'s record ``out`` and status (planned
        from this follower's current state with step ``dt``)."""
        path = self.path
        if status == FALLBACK:  # the failsafe already held
            held = self._stop
            d, j = cut_phases(held.profile.durs, held.profile.jerks, dt)
            prof = ScalarProfile(self._s, self._v, self._a, d, j)
            return FollowerStep(dt, path, prof, prof.end, held.advanced(dt), True)
        _, s0, v0, a0 = record_start(out, O_HEAD, H_CAP)
        return FollowerStep.recorded(dt, path, (s0, v0, a0), out.tolist(), status)

    def commit(self, step: FollowerStep, at_end: JointState | None = None) -> JointState:
        """Apply a step from :meth:`peek` (of this follower, in its current state).

        ``at_end``: the joint state at the end of the step if the caller already sampled it
        (a shielded trajectory's sample 1); returned as is unless the path ends with this step.
        """
        if step.path is not self.path or step.start != (self._s, self._v, self._a):
            raise RobotModelError(
                "step was planned for another path or state; call peek() again before commit()"
            )
        self._s, self._v, self._a = step.end
        self._held = step  # its stop, made when first needed (FollowerStep)
        self._t += step.dt
        if step.fallback:
            self.fallback_steps += 1
        if self.done:
            self._s, self._v, self._a = self._S, 0.0, 0.0
            self._stop = self._rest_stop(self.path, self._S)
            pending = self._pending
            if pending is not None:
                self._pending = None
                self._start_from_rest(pending)
            return self.state
        return self.state if at_end is None else at_end

    def step(self, dt: float) -> JointState:
        """Advance ``dt`` seconds along the path; returns the joint state at the end."""
        return self.commit(self.peek(dt))

    def brake(self, dt: float) -> JointState:
        """Advance ``dt`` seconds along the failsafe held (the verified stop)."""
        held = self._stop
        d, j = cut_phases(held.profile.durs, held.profile.jerks, dt)
        prof = ScalarProfile(self._s, self._v, self._a, d, j)
        return self.commit(FollowerStep(dt, self.path, prof, prof.end, held.advanced(dt), True))

    # -- replanning ----------------------------------------------------------------------------

    def _start_from_rest(self, wps: np.ndarray) -> None:
        q_now = self.path.q(self._s)
        pts = np.vstack([q_now[None, :], wps])
        path = PathTrajectory(pts, blend_distance=self.blend_distance, limits=self.limits)
        self._set_path(path, 0.0, 0.0, 0.0, None)

    def replan(self, new_waypoints: object) -> None:
        """Continue through ``new_waypoints`` ``(W, n)`` from the current state without stopping.

        The new path keeps the current geometry over the stopping distance of the failsafe held
        (which therefore stays valid), runs straight on in the current direction to a corner,
        blended into the first new waypoint, and then through the others. If the robot is at
        rest the new path simply starts at the current position.
        """
        n = self.path.n_joints
        wps = check_waypoints(new_waypoints, self.limits, n)
        # a planner re-sending the same goal changes nothing
        goal = self._goal
        if goal is not None and goal.shape == wps.shape and np.array_equal(goal, wps):
            return
        self._goal = wps
        if len(wps) == 1 and np.linalg.norm(wps[0] - self.path.q(self._S)) <= S_TOL:
            return
        self._pending = None
        if self._v <= REST_V and abs(self._a) <= REST_A:
            self._start_from_rest(wps)
            return
        path, stop = self.path, self._stop
        p = path._p
        if p is None:  # a moving robot is on a path with pieces
            raise RobotModelError("replan: the robot moves on a path without pieces")
        # junction on a straight piece at or after the end of the held stop (the last piece of
        # a path is always straight)
        s_min = min(stop.s_end, self._S)
        k = path.piece_index(s_min)
        while p.blend[k] and k + 1 < path.n_pieces:
            k += 1
        s_b = max(s_min, self._path_s0(k))
        u = p.u[k]
        q_b = path.q(s_b)
        lim = self._lim
        with np.errstate(divide="ignore", invalid="ignore"):
            room_j = np.where(
                u > 0, (lim.q_max - q_b) / u, np.where(u < 0, (lim.q_min - q_b) / u, np.inf)
            )
        room = float(np.min(room_j))
        s_off = s_b - self._s
        # waypoints the held stop already ends on are reached
        first = 0
        while first < len(wps) and np.linalg.norm(wps[first] - q_b) <= 1e-6:
            first += 1
        rest = wps[first:]
        if len(rest) == 0:
            new_path = path.continued(self._s, s_b, rest, wps, self.blend_distance)
            self._set_path(new_path, 0.0, self._v, self._a, stop.rebased(new_path, -self._s))
            return
        # the corner may not lie beyond half the way to the first new waypoint
        reach_w0 = 0.5 * float(np.linalg.norm(rest[0] - q_b))
        extra = 0.0
        for _ in range(4):
            # straight run-in along the current direction (inside the joint position box),
            # then the new corner; move the corner further while the follower could not slow
            # down to the corner's admissible speed before it
            run = min(self.blend_distance, room - extra, reach_w0 if extra == 0.0 else np.inf)
            if run < 1e-6:
                # the robot cannot go on straight far enough before a joint limit: finish the
                # held stop and start the new path from rest
                self._pending = wps
                return
            q_c = q_b + (extra + run) * u
            new_path = path.continued(
                self._s, s_b, np.vstack([q_c[None, :], rest]), wps, self.blend_distance
            )
            starts = new_path.piece_starts
            corner = np.flatnonzero(new_path.piece_is_blend & (starts >= s_off - S_TOL))
            if corner.size == 0:
                break
            kc = int(corner[0])
            V, A, J = piece_boxes(new_path, self._lim, self.tangential_share)
            A_w, J_w = float(A[: kc + 1].min()), float(J[: kc + 1].min())
            d, j = velocity_phases(self._v, self._a, float(V[kc]), A_w, J_w)
            reach = phases_end(0.0, self._v, self._a, d, j)[0]
            free = float(starts[kc])
            if reach <= free:
                break
            if extra == 0.0 and self._S - s_min <= self.blend_distance:
                # already braking to a standstill near the end of the current path, too close
                # to turn: finish the path and start the new one from rest
                self._pending = wps
                return
            extra += reach - free + 1e-6
        self._set_path(new_path, 0.0, self._v, self._a, stop.rebased(new_path, -self._s))

    # -- offline time-scaling --------------------------------------------------------------------

    def rollout(
        self, dt: float, t_max: float, sample_dt: float | None = None
    ) -> tuple[np.ndarray, ...]:
        """Step until done (or ``t_max``); returns dense samples ``(t, s, sd, sdd)``.

        ``sample_dt`` (default ``dt``) must divide ``dt``: the committed motion is sampled
        inside every step.
        """
        sub = 1 if sample_dt is None else max(1, int(round(dt / sample_dt)))
        local = np.arange(sub) * (dt / sub)
        ts, ss, vs, as_ = [], [], [], []
        while not self.done and self._t < t_max - 1e-12:
            st = self.peek(dt)
            s, v, a = st.profile.evaluate(local)
            ts.append(self._t + local)
            ss.append(s)
            vs.append(v)
            as_.append(a)
            self.commit(st)
        ts.append(np.array([self._t]))
        ss.append(np.array([self._s]))
        vs.append(np.array([self._v]))
        as_.append(np.array([self._a]))
        return tuple(np.concatenate(x) for x in (ts, ss, vs, as_))


def time_scaling(
    path: PathTrajectory, limits: JointLimits, dt: float = 1e-3, t_max: float = 600.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Offline time-scaling of ``path`` from rest to rest: samples ``(t, s, s', s'')`` every
    ``dt`` seconds, produced by a :class:`PathFollower` (same limits and guarantees)."""
    t, s, sd, sdd = PathFollower(path, limits).rollout(dt, t_max)
    return t, s, sd, sdd
