"""Sampling check of Liu et al. 2022 eq. 7: at states on the boundary ``phi = 0``, is there a jerk
in the box that does not increase ``phi``?

``max_{x: phi(x) = 0} min_{u in U} phi'(x, u) <= 0``, approximated as the paper does, by samples.
A sample: a random configuration within the position limits, joint velocities and accelerations
uniform in ``+-state_fraction`` of their limits, a random point on a random moving link's
capsule axis, a random direction ``n`` and a human point velocity uniform in a ball of
``human_speed_mps``; the distance along ``n`` is then solved (bisection on a grid) so that
``phi = 0`` (every root in ``[0, 3] m``). ``phi'`` is the one-cycle change
``(phi_{k+1}(u*) - phi_k) / tau`` under the discrete model, at the box vertex ``u*`` that
minimises the linearised ``phi_{k+1}`` and evaluated EXACTLY (no linearisation), so a sample
counts as feasible only if that vertex really keeps ``phi`` from growing.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from sara_app.robot.model import RobotModel
from sara_app.safety.jssa import JssaController, JssaParams
from sara_app.safety.jssa_index import index_terms, predict_delta, safety_index
from sara_app.safety.jssa_kernels import constraint_terms

HUMAN_RADIUS_M = 0.05
"""Radius of the sampled human capsule (an arm, Schepp et al. 2022 Table I thickness 0.1 m)."""


class FeasibilityReport(NamedTuple):
    n_states: int  # boundary states found (a sample may give 0, 1 or 2)
    n_violations: int  # states where no vertex keeps phi from growing
    worst_phi_rate: float  # max over states of min_u phi' (1/s * m^2); eq. 7 wants <= 0
    worst_state: dict[str, float]  # d, d', d'' of the worst state


def _roots(f: np.ndarray, grid: np.ndarray) -> list[tuple[float, float]]:
    idx = np.flatnonzero(np.sign(f[:-1]) * np.sign(f[1:]) < 0)
    return [(float(grid[i]), float(grid[i + 1])) for i in idx]


def check_feasibility(
    robot: RobotModel,
    params: JssaParams,
    n_samples: int = 1000,
    seed: int = 0,
    tau: float = 0.008,
    human_speed_mps: float = 1.6,
    state_fraction: float = 0.5,
) -> FeasibilityReport:
    """Eq. 7 by sampling; see the module doc. Deterministic for a given ``seed``."""
    ctrl = JssaController(robot, params)
    rng = np.random.default_rng(seed)
    lim = robot.limits
    lo, hi = ctrl.jerk_lo, ctrl.jerk_hi
    grid = np.linspace(0.0, 3.0, 301)
    p = params
    worst, worst_state, n_states, n_bad = -np.inf, {}, 0, 0
    for _ in range(n_samples):
        q = lim.q_min + rng.random(robot.n_dof) * (lim.q_max - lim.q_min)
        qd = state_fraction * lim.v_max * rng.uniform(-1, 1, robot.n_dof)
        qdd = state_fraction * lim.a_max * rng.uniform(-1, 1, robot.n_dof)
        link = int(rng.choice(ctrl.moving_links))
        ends, radius = robot.link_capsules(q)
        p_r = ends[link, 0] + rng.random() * (ends[link, 1] - ends[link, 0])
        ctrl.kin.update(q, qd, qdd)
        v_r, a_r, c_r, J_r = ctrl.kin.points(np.array([link]), p_r[None])
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        v_o = rng.normal(size=3)
        v_o *= human_speed_mps * rng.random() ** (1 / 3) / np.linalg.norm(v_o)
        r_sum = np.array([radius[link] + HUMAN_RADIUS_M])
        # phi as a function of the surface distance along n
        D = grid + r_sum[0]
        dp = D[:, None] * n
        dv = np.broadcast_to(v_r[0] - v_o, dp.shape)
        da = np.broadcast_to(a_r[0], dp.shape)
        d, d1, d2 = index_terms(dp, dv, da, np.full(len(grid), r_sum[0]))
        phi = safety_index(d, d1, d2, p.d_min_m, p.lambda_1, p.lambda_2)

        def phi_at(dist: float, n=n, dv=dv, da=da, r_sum=r_sum) -> float:
            dm, d1m, d2m = index_terms(((dist + r_sum[0]) * n)[None], dv[:1], da[:1], r_sum)
            return float(safety_index(dm, d1m, d2m, p.d_min_m, p.lambda_1, p.lambda_2)[0])

        for a, b in _roots(phi, grid):
            fa = phi_at(a)
            for _ in range(40):  # bisection to ~3e-12 m
                mid = 0.5 * (a + b)
                fm = phi_at(mid)
                if np.sign(fm) == np.sign(fa):
                    a, fa = mid, fm
                else:
                    b = mid
            dist = 0.5 * (a + b)
            p_o = p_r - (dist + r_sum[0]) * n
            rate = _min_rate(p_r[None], v_r, a_r, c_r, J_r, p_o[None], v_o[None], r_sum, tau, p,
                             lo, hi)  # fmt: skip
            n_states += 1
            n_bad += int(rate > 0.0)
            if rate > worst:
                dpn = (p_r - p_o)[None]
                _, w1, w2 = index_terms(dpn, (v_r[0] - v_o)[None], a_r, r_sum)
                worst = rate
                worst_state = {"d_m": dist, "d_dot": float(w1[0]), "d_ddot": float(w2[0])}
    return FeasibilityReport(n_states, n_bad, float(worst), worst_state)


def _min_rate(
    p_r: np.ndarray,
    v_r: np.ndarray,
    a_r: np.ndarray,
    c_r: np.ndarray,
    J_r: np.ndarray,
    p_o: np.ndarray,
    v_o: np.ndarray,
    r_sum: np.ndarray,
    tau: float,
    p: JssaParams,
    lo: np.ndarray,
    hi: np.ndarray,
) -> float:
    """``(phi_{k+1}(u*) - phi_k) / tau`` with ``u*`` the vertex minimising the linearisation."""
    K, n = J_r.shape[0], J_r.shape[2]
    d, d1, d2, phi, phi0 = (np.empty(K) for _ in range(5))
    g = np.empty((K, n))
    # the live filter's own linearisation (sara_app.safety.jssa.JssaController), material points
    p_r, v_r, a_r, c_r, J_r, p_o, v_o, r_sum = (
        np.ascontiguousarray(x, dtype=float) for x in (p_r, v_r, a_r, c_r, J_r, p_o, v_o, r_sum)
    )
    constraint_terms(p_r, v_r, a_r, c_r, J_r, p_o, v_o, r_sum, np.zeros(K), float(tau),
                     p.d_min_m, p.lambda_1, p.lambda_2, d, d1, d2, phi, phi0, g)  # fmt: skip
    phi_k = float(phi[0])
    u = np.where(g[0] > 0.0, lo, hi)
    jerk = c_r + np.einsum("kin,n->ki", J_r, u)
    dp, dv, da = predict_delta(p_r, v_r, a_r, jerk, p_o, v_o, tau)
    dn, dn1, dn2 = index_terms(dp, dv, da, r_sum)
    phi_next = float(safety_index(dn, dn1, dn2, p.d_min_m, p.lambda_1, p.lambda_2)[0])
    return (phi_next - phi_k) / tau
