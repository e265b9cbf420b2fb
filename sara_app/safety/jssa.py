"""Jerk-based safe set algorithm, JSSA (Liu et al. 2022): a per-cycle safety filter on the joint
jerk.

Every control cycle :meth:`JssaController.step` takes the robot state ``(q, q', q'')``, the
nominal jerk ``u0`` and the humans' (and static obstacles') capsules with their end-point
velocities, and returns the jerk closest to ``u0`` (weighted by ``V = diag(weights)``) that keeps
the linearised safety index of the next state non-positive (eq. 13-14) within the box jerk
bounds. The robot model is eq. 1 (:func:`integrate`), humans move at constant velocity (eq. 4).

Modes: ``single`` (the paper: one constraint, the critical pair of minimum capsule distance over
the moving links, solved exactly) and ``multi`` (the paper's future work: one constraint per
capsule pair closer than ``consider_distance_m``, at most ``max_constraints`` of the closest,
solved with DAQP through qpsolvers).

Constraint. By default (``eta_per_s = None``, the paper's eq. 13) ``phi_{k+1} <= 0``. With
``eta_per_s`` set, ``phi_{k+1} <= max(0, phi_k - eta tau)``: inside the set it stays inside
(eq. 5), outside it decreases by ``eta tau`` per cycle (the SSA rule ``phi' <= -eta``), which
avoids demanding a jump back into the set in one cycle.

Jerk box. The paper's ``U`` is the jerk box ``|u| <= j_max``. With ``joint_limits`` (default)
the box is narrowed, per joint, so that the next acceleration ``a1`` stays in ``[-a_lo, a_hi]``:
``a_max``, and the largest ``a1`` whose velocity at the end of the step (eq. 1) plus a
jerk-limited ramp of ``a1`` down to 0 stays under ``v_max`` (``v + tau (a + a1) / 2 +
a1^2 / (2 j_max) <= v_max``), and the mirror image. It is always non-empty and inside the jerk
box, so the exact one-constraint solution still applies. Position limits are not enforced (nor
are they in the paper).

Fallback. Invalid inputs (NaN, wrong shapes, missing human data), an infeasible projection or a
non-finite intermediate give the brake of :func:`sara_app.safety.jssa_qp.brake_jerk`; the result
says why and the controller counts it. Invalid parameters raise at construction.

Static links (the base, and links whose capsule axis lies on the first joint's axis, so that no
joint moves it by more than ``STATIC_LINK_M_PER_RAD``: the Panda's ``link1``, fitted 1e-5 m off
its axis) cannot change their distance to anything and are left out
of the critical-pair search: a human next to them is not the controller's to avoid.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from sara_app.errors import ParameterError
from sara_app.geometry.shape_kernels import pair_distances, segment_closest
from sara_app.robot.model import JointLimits, RobotModel
from sara_app.safety.jssa_kernels import constraint_terms, project_halfspace_box, sliding_terms
from sara_app.safety.jssa_kinematics import PointKinematics
from sara_app.safety.jssa_qp import FEAS_TOL, brake_jerk, project_polytope_box
from sara_app.safety.settings import check_index_roots


class JssaParams(BaseModel):
    """JSSA parameters; ``lambda_1`` in m s, ``lambda_2`` in m s^2 so that phi is in m^2."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    d_min_m: float = Field(default=0.05, gt=0.0, le=2.0)
    lambda_1: float = Field(default=3.0, gt=0.0, le=1e3)
    lambda_2: float = Field(default=1.0, ge=0.0, le=1e3)
    mode: Literal["single", "multi"] = "single"
    weights: tuple[float, ...] | None = None
    eta_per_s: float | None = Field(default=None, ge=0.0)
    joint_limits: bool = True
    consider_distance_m: float = Field(default=2.0, gt=0.0)
    max_constraints: int = Field(default=16, ge=1, le=256)
    brake_omega_per_s: float = Field(default=10.0, gt=0.0)
    jerk_scale: float = Field(default=1.0, gt=0.0, le=1.0)
    sliding: bool = False
    """Correct ``d''`` for closest points that slide along the capsule axes (not in the paper;
    see :mod:`sara_app.safety.jssa_index`). Off: the paper's eq. 12 (material points)."""

    @model_validator(mode="after")
    def _real_negative_roots(self) -> JssaParams:
        check_index_roots(self.lambda_1, self.lambda_2)
        if self.weights is not None and not all(np.isfinite(w) and w > 0 for w in self.weights):
            raise ValueError(f"weights = {self.weights}; expected positive finite values")
        return self


def make_params(**kwargs: object) -> JssaParams:
    """:class:`JssaParams` from keywords, raising :class:`ParameterError` on bad values."""
    try:
        return JssaParams(**kwargs)  # type: ignore[arg-type]
    except ValidationError as exc:
        raise ParameterError(f"invalid JSSA parameters: {exc}") from None


@dataclass
class JssaResult:
    """One cycle's output. Points are world-frame surface points of the critical pair (the
    dashboard's line); ``link_index`` into ``robot.link_names``, ``other_index`` into the humans'
    capsules then the obstacles' (``-1``: no pair). ``phi`` is the current index of that pair."""

    jerk: np.ndarray
    phi: float
    active: bool
    fallback: bool
    reason: str = ""
    link_index: int = -1
    other_index: int = -1
    other_is_obstacle: bool = False
    robot_point: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    other_point: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    distance_m: float = float("inf")
    d_dot: float = 0.0
    d_ddot: float = 0.0
    n_constraints: int = 0
    uncontrollable: int = 0
    rel_vel: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rel_acc: np.ndarray = field(default_factory=lambda: np.zeros(3))


@dataclass
class Pairs:
    """Critical pairs of one cycle, ``K`` of them (world frame): robot axis points ``p_r`` with
    velocity, acceleration, drift jerk ``(K, 3)`` and Jacobian ``J_r (K, 3, n)``; other axis
    points ``p_o`` with velocity ``v_o`` ``(K, 3)``; radius sums ``r_sum (K,)``; ``slide (K,)``
    the sliding correction of ``d''`` (:mod:`sara_app.safety.jssa_index`)."""

    p_r: np.ndarray
    v_r: np.ndarray
    a_r: np.ndarray
    c_r: np.ndarray
    J_r: np.ndarray
    p_o: np.ndarray
    v_o: np.ndarray
    r_sum: np.ndarray
    slide: np.ndarray | float = 0.0


def integrate(
    q: np.ndarray, q_dot: np.ndarray, q_ddot: np.ndarray, u: np.ndarray, tau: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One step of the jerk-controlled robot (eq. 1): ``(q, q', q'')`` at ``t + tau``."""
    q1 = q + tau * q_dot + tau * tau / 2.0 * q_ddot + tau**3 / 6.0 * u
    return q1, q_dot + tau * q_ddot + tau * tau / 2.0 * u, q_ddot + tau * u


def _finite(x: object, shape: tuple[int, ...]) -> np.ndarray | None:
    if x is None:
        return None
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        return None
    if a.shape != shape or not np.isfinite(a.sum()):
        return None
    return a


UNCONTROLLABLE_PHI_M2 = 1e-3
"""A pair whose next index the whole jerk box changes by less than this (m^2) is dropped."""

STATIC_LINK_M_PER_RAD = 1e-3
"""A link whose capsule axis ends move less than this per unit joint speed (m/rad) is static."""


def _moving_links(robot: RobotModel, kin: PointKinematics) -> np.ndarray:
    """Links whose capsule axis some joint moves, at random configurations: ``(L',)`` int."""
    rng = np.random.default_rng(0)
    lim = robot.limits
    moved = np.zeros(robot.n_links, dtype=bool)
    links = np.repeat(np.arange(robot.n_links), 2)
    for _ in range(3):
        q = lim.q_min + rng.random(robot.n_dof) * (lim.q_max - lim.q_min)
        ends, _ = robot.link_capsules(q)
        kin.update(q, np.zeros(robot.n_dof), np.zeros(robot.n_dof))
        J = kin.points(links, ends.reshape(-1, 3))[3]  # (2L, 3, n)
        moved |= np.abs(J).reshape(robot.n_links, -1).max(axis=1) > STATIC_LINK_M_PER_RAD
    return np.flatnonzero(moved)


def _closest_params(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest-point parameters ``(K, 1)`` on segments ``a`` and ``b`` ``(K, 2, 3)`` (compiled
    :func:`sara_app.geometry.shape_kernels.segment_closest`, one call per pair)."""
    K = a.shape[0]
    s, t = np.empty((K, 1)), np.empty((K, 1))
    for k in range(K):
        (ax, ay, az), (bx, by, bz) = a[k].tolist()
        (cx, cy, cz), (dx, dy, dz) = b[k].tolist()
        _, s[k, 0], t[k, 0] = segment_closest(ax, ay, az, bx, by, bz, cx, cy, cz, dx, dy, dz)
    return s, t


def _ramp_acc(room: np.ndarray, j: np.ndarray, tau: float) -> np.ndarray:
    """Largest next acceleration ``a1 (n,)`` with ``tau a1 / 2 + a1^2 / (2 j) <= room``: the
    velocity at the end of the step (eq. 1: ``v + tau (a + a1) / 2``) plus a jerk-``j`` ramp of
    ``a1`` down to 0 stays below the limit (``room = v_max - v - tau a / 2``)."""
    return j * (np.sqrt(0.25 * tau * tau + 2.0 * np.maximum(room, 0.0) / j) - 0.5 * tau)


def _or_zeros(x: object, n: int) -> np.ndarray:
    """``x`` as ``(n,)`` with non-finite entries zeroed, or zeros when it cannot be read."""
    try:
        a = np.asarray(x, dtype=float)
    except (TypeError, ValueError):
        return np.zeros(n)
    return np.nan_to_num(a, nan=0.0, posinf=0.0, neginf=0.0) if a.shape == (n,) else np.zeros(n)


class JssaController:
    """Per-cycle JSSA filter for one robot. Not thread-safe (owns buffers).

    ``limits``: the joint velocity, acceleration and jerk limits of the jerk box (default the
    robot's own; a cell passes its task's scaled limits)."""

    def __init__(
        self,
        robot: RobotModel,
        params: JssaParams | None = None,
        limits: JointLimits | None = None,
    ) -> None:
        self.robot = robot
        self.params = params or JssaParams()
        self.limits = robot.limits if limits is None else limits
        n = robot.n_dof
        w = self.params.weights
        if w is not None and len(w) != n:
            raise ParameterError(
                f"weights has {len(w)} entries; expected {n} (one per joint of {robot.name})"
            )
        self.weights = np.ones(n) if w is None else np.array(w, dtype=float)
        self.kin = PointKinematics(robot)
        self.moving_links = _moving_links(robot, self.kin)
        self.jerk_hi = self.params.jerk_scale * np.asarray(self.limits.j_max, dtype=float)
        self.jerk_lo = -self.jerk_hi
        self._ends = np.zeros((robot.n_links, 2, 3))
        self._r_moving = np.asarray(robot.radius_m)[self.moving_links]
        self.n = n
        self.stats = {
            "cycles": 0,
            "active": 0,
            "fallback": 0,
            "invalid_input": 0,
            "uncontrollable": 0,
        }

    # -- helpers ---------------------------------------------------------------------------------

    def _brake(self, q_dot: np.ndarray, q_ddot: np.ndarray, reason: str) -> JssaResult:
        self.stats["fallback"] += 1
        return self.brake(q_dot, q_ddot, reason)

    def brake(self, q_dot: np.ndarray, q_ddot: np.ndarray, reason: str) -> JssaResult:
        """The fallback brake (:func:`~sara_app.safety.jssa_qp.brake_jerk`) as a result, not
        counted as a fallback of the filter (callers braking for their own faults)."""
        u = brake_jerk(q_dot, q_ddot, self.jerk_lo, self.jerk_hi, self.params.brake_omega_per_s)
        return JssaResult(jerk=u, phi=float("inf"), active=True, fallback=True, reason=reason)

    def _others(
        self, ends: object, radius: object, vel: object, what: str
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | str:
        try:
            e = np.asarray(ends, dtype=float) if ends is not None else None
        except (TypeError, ValueError):
            e = None
        if e is None or e.ndim != 3 or e.shape[1:] != (2, 3):
            return f"{what} ends missing or not (M, 2, 3)"
        m = e.shape[0]
        e2, r = _finite(e, (m, 2, 3)), _finite(radius, (m,))
        v = np.zeros((m, 2, 3)) if vel is None and what == "obstacle" else _finite(vel, (m, 2, 3))
        if e2 is None or r is None or v is None or np.any(r < 0):
            return f"{what} capsules invalid (NaN, negative radius or shape mismatch)"
        return e2, r, v

    # -- the cycle -------------------------------------------------------------------------------

    def step(
        self,
        q: np.ndarray,
        q_dot: np.ndarray,
        q_ddot: np.ndarray,
        nominal_jerk: np.ndarray,
        human_ends: np.ndarray | None,
        human_radius: np.ndarray | None,
        human_vel: np.ndarray | None,
        dt: float,
        obstacle_ends: np.ndarray | None = None,
        obstacle_radius: np.ndarray | None = None,
    ) -> JssaResult:
        """One JSSA cycle. Humans: ends ``(M, 2, 3)``, radii ``(M,)``, end velocities
        ``(M, 2, 3)`` (world frame, m, m/s; ``M = 0`` allowed, ``None`` = missing → brake).
        Static obstacles: capsules ``(K, 2, 3)``, ``(K,)``. ``dt`` is the cycle time (s).
        Never raises on bad inputs: returns the fallback brake instead."""
        self.stats["cycles"] += 1
        n = self.n
        state = [_finite(x, (n,)) for x in (q, q_dot, q_ddot, nominal_jerk)]
        if not (np.isfinite(dt) and dt > 0.0):
            state.append(None)
        if any(x is None for x in state):
            self.stats["invalid_input"] += 1
            qd, qdd = _or_zeros(q_dot, n), _or_zeros(q_ddot, n)
            return self._brake(qd, qdd, "invalid robot state, nominal jerk or dt")
        q, q_dot, q_ddot, u0 = (x for x in state if x is not None)
        humans = self._others(human_ends, human_radius, human_vel, "human")
        if isinstance(humans, str):
            self.stats["invalid_input"] += 1
            return self._brake(q_dot, q_ddot, humans)
        parts = [humans]
        if obstacle_ends is not None:
            obst = self._others(obstacle_ends, obstacle_radius, None, "obstacle")
            if isinstance(obst, str):
                self.stats["invalid_input"] += 1
                return self._brake(q_dot, q_ddot, obst)
            parts.append(obst)
        o_ends = np.concatenate([p[0] for p in parts])
        o_r = np.concatenate([p[1] for p in parts])
        o_v = np.concatenate([p[2] for p in parts])
        n_humans = humans[0].shape[0]
        try:
            return self._solve(q, q_dot, q_ddot, u0, o_ends, o_r, o_v, n_humans, float(dt))
        except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
            return self._brake(q_dot, q_ddot, f"numerical failure: {exc}")

    def _solve(
        self,
        q: np.ndarray,
        q_dot: np.ndarray,
        q_ddot: np.ndarray,
        u0: np.ndarray,
        o_ends: np.ndarray,
        o_r: np.ndarray,
        o_v: np.ndarray,
        n_humans: int,
        tau: float,
    ) -> JssaResult:
        p = self.params
        if o_ends.shape[0] == 0:
            lo, hi = self.jerk_box(q_dot, q_ddot, tau)
            return JssaResult(jerk=np.clip(u0, lo, hi), phi=-np.inf, active=False, fallback=False)
        ends, _ = self.robot.link_capsules(q, out_ends=self._ends)
        r_ends = ends[self.moving_links]
        dist3 = np.empty((1, r_ends.shape[0], o_ends.shape[0]))
        pair_distances(r_ends[None], self._r_moving[None], o_ends[None], o_r[None], dist3)
        dist = dist3[0]
        if p.mode == "single":
            flat = np.array([int(np.argmin(dist))])
        else:
            order = np.argsort(dist, axis=None)[: p.max_constraints]
            flat = order[dist.ravel()[order] < p.consider_distance_m]
            if flat.size == 0:
                flat = order[:1]
        li, oi = np.unravel_index(flat, dist.shape)
        e_r, e_o, v_o_ends = r_ends[li], o_ends[oi], o_v[oi]
        sk, tk = _closest_params(e_r, e_o)
        p_r = e_r[:, 0] + sk * (e_r[:, 1] - e_r[:, 0])
        p_o = e_o[:, 0] + tk * (e_o[:, 1] - e_o[:, 0])
        v_o = v_o_ends[:, 0] + tk * (v_o_ends[:, 1] - v_o_ends[:, 0])
        r_sum = self._r_moving[li] + o_r[oi]
        links = self.moving_links[li]
        self.kin.update(q, q_dot, q_ddot)
        v_r, a_r, c_r, J_r = self.kin.points(links, p_r)
        slide = np.zeros(len(links))
        if p.sliding:
            sliding_terms(
                p_r - p_o, v_r - v_o, e_r[:, 1] - e_r[:, 0], self.kin.angular_velocity(links),
                e_o[:, 1] - e_o[:, 0], v_o_ends[:, 1] - v_o_ends[:, 0], sk[:, 0], tk[:, 0], slide,
            )  # fmt: skip
        pairs = Pairs(p_r, v_r, a_r, c_r, J_r, p_o, v_o, r_sum, slide)
        res, d, d_dot, d_ddot, phi_k = self._filter(q_dot, q_ddot, u0, pairs, tau)
        k = int(np.argmin(d))  # the critical pair (minimum distance)
        nrm = (p_r[k] - p_o[k]) / max(float(np.linalg.norm(p_r[k] - p_o[k])), 1e-12)
        res.phi, res.distance_m = float(phi_k[k]), float(d[k])
        res.d_dot, res.d_ddot = float(d_dot[k]), float(d_ddot[k])
        res.link_index, res.other_index = int(links[k]), int(oi[k])
        res.other_is_obstacle = bool(oi[k] >= n_humans)
        res.robot_point = p_r[k] - self._r_moving[li[k]] * nrm
        res.other_point = p_o[k] + o_r[oi[k]] * nrm
        res.n_constraints = len(flat)
        res.rel_vel, res.rel_acc = v_r[k] - v_o[k], a_r[k].copy()
        return res

    def jerk_box(
        self, q_dot: np.ndarray, q_ddot: np.ndarray, tau: float
    ) -> tuple[np.ndarray, np.ndarray]:
        """The admissible jerk box ``(lo, hi)`` ``(n,)`` for this cycle (see the module doc)."""
        if not self.params.joint_limits:
            return self.jerk_lo, self.jerk_hi
        lim = self.limits
        j, a_max, v_max = self.jerk_hi, lim.a_max, lim.v_max
        a_hi = np.minimum(a_max, _ramp_acc(v_max - q_dot - 0.5 * tau * q_ddot, j, tau))
        a_lo = -np.minimum(a_max, _ramp_acc(v_max + q_dot + 0.5 * tau * q_ddot, j, tau))
        a_hi = np.maximum(a_hi, a_lo)
        hi = np.minimum(j, np.maximum((a_hi - q_ddot) / tau, -j))
        lo = np.maximum(-j, np.minimum((a_lo - q_ddot) / tau, j))
        return lo, hi

    def _filter(
        self, q_dot: np.ndarray, q_ddot: np.ndarray, u0: np.ndarray, pr: Pairs, tau: float
    ) -> tuple[JssaResult, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """JSSA: linearised constraint (eq. 13) and projection (eq. 14) of ``u0``.

        Returns the result and the pairs' current ``d, d', d'', phi`` ``(K,)``."""
        p = self.params
        lo, hi = self.jerk_box(q_dot, q_ddot, tau)
        K, n = pr.J_r.shape[0], pr.J_r.shape[2]
        d, d_dot, d_ddot, phi_k, phi0 = (np.empty(K) for _ in range(5))
        g = np.empty((K, n))
        slide = np.broadcast_to(np.asarray(pr.slide, dtype=float), (K,)).copy()
        constraint_terms(
            pr.p_r, pr.v_r, pr.a_r, pr.c_r, pr.J_r, pr.p_o, pr.v_o, pr.r_sum, slide,
            tau, p.d_min_m, p.lambda_1, p.lambda_2, d, d_dot, d_ddot, phi_k, phi0, g,
        )  # fmt: skip
        bound = 0.0 if p.eta_per_s is None else np.maximum(phi_k - p.eta_per_s * tau, 0.0)
        b = bound - phi0
        if not (np.all(np.isfinite(g)) and np.all(np.isfinite(b))):
            return self._brake(q_dot, q_ddot, "non-finite constraint"), d, d_dot, d_ddot, phi_k
        # Pairs the jerk box can hardly influence (points on or next to a joint axis that no
        # other joint moves) are uncontrollable: their constraint is dropped and counted.
        reach = np.abs(g) @ (hi - lo)
        keep = reach > UNCONTROLLABLE_PHI_M2
        n_drop = int(g.shape[0] - np.count_nonzero(keep))
        self.stats["uncontrollable"] += n_drop
        g, b = g[keep], b[keep]
        active = bool(np.any(g @ np.clip(u0, lo, hi) > b))
        if g.shape[0] == 0:
            u, ok = np.clip(u0, lo, hi), True
        elif p.mode == "single":
            u = np.empty(self.n)
            mu = project_halfspace_box(u0, self.weights, g[0], float(b[0]), lo, hi, FEAS_TOL, u)
            ok = mu < np.inf
        else:
            u, ok = project_polytope_box(u0, self.weights, g, b, lo, hi)
        if not ok:
            res = self._brake(q_dot, q_ddot, "infeasible projection")
        else:
            self.stats["active"] += int(active)
            res = JssaResult(jerk=u, phi=0.0, active=active, fallback=False)
        res.uncontrollable = n_drop
        return res, d, d_dot, d_ddot, phi_k
