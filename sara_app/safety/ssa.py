"""The SSA baseline of Liu et al. 2022 Sec. 4.3: acceleration-level safe set algorithm, jerk
saturated.

Index ``phi = d_min^2 - d|d| - lambda_1 d'`` (relative degree 2 to the joint acceleration).
Per cycle, with the acceleration ``a`` applied over the step (``p'' = a_r + J (a - q''_k)``):
``phi_{k+1}(a) ~ phi(Delta) + g . (a - q''_k)`` with ``g = (tau^2/2 dphi/dp + tau dphi/dv) J``.
The nominal acceleration ``a_0 = q''_k + tau u_0`` is projected onto ``phi_{k+1} <= max(0,
phi_k - eta tau)`` WITHOUT bounds (the original SSA assumes unbounded acceleration), then the jerk
``u = (a_S - q''_k) / tau`` is saturated at the jerk bounds, which may break the constraint: that
is the baseline's weakness the paper measures. ``saturated`` counts cycles where any joint's jerk
was clipped.

Geometry, critical pair, kinematics and fallbacks are those of
:class:`sara_app.safety.jssa.JssaController`; only the filter differs.
"""

from __future__ import annotations

import numpy as np

from sara_app.robot.model import JointLimits, RobotModel
from sara_app.safety.jssa import JssaController, JssaParams, JssaResult, Pairs
from sara_app.safety.jssa_index import index_gradient, index_terms, safety_index


class SsaController(JssaController):
    """Acceleration-level SSA with saturated jerk; same API as :class:`JssaController`.

    ``params.lambda_2`` is ignored (SSA has no second-derivative term) and only ``single`` mode
    exists (the paper's baseline); the paper uses ``lambda_1 = 3``."""

    def __init__(
        self,
        robot: RobotModel,
        params: JssaParams | None = None,
        limits: JointLimits | None = None,
    ) -> None:
        params = params or JssaParams()
        update = {"lambda_2": 0.0, "mode": "single"}
        super().__init__(robot, params.model_copy(update=update), limits)
        self.stats["saturated"] = 0

    def _filter(
        self, q_dot: np.ndarray, q_ddot: np.ndarray, u0: np.ndarray, pr: Pairs, tau: float
    ) -> tuple[JssaResult, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        p = self.params
        d, d_dot, d_ddot = index_terms(pr.p_r - pr.p_o, pr.v_r - pr.v_o, pr.a_r, pr.r_sum)
        phi_k = safety_index(d, d_dot, d_ddot, p.d_min_m, p.lambda_1, 0.0)
        # Delta: next relative position and velocity at a = q''_k (the robot's current p'').
        dp = pr.p_r + tau * pr.v_r + 0.5 * tau * tau * pr.a_r - (pr.p_o + tau * pr.v_o)
        dv = pr.v_r + tau * pr.a_r - pr.v_o
        zero = np.zeros_like(dp)
        dn, dnd, _ = index_terms(dp, dv, zero, pr.r_sum)
        phi0 = safety_index(dn, dnd, 0.0 * dnd, p.d_min_m, p.lambda_1, 0.0)
        _, g_p, g_v, _ = index_gradient(dp, dv, zero, pr.r_sum, p.lambda_1, 0.0)
        g = np.einsum("i,in->n", 0.5 * tau * tau * g_p[0] + tau * g_v[0], pr.J_r[0])
        bound = 0.0 if p.eta_per_s is None else max(float(phi_k[0]) - p.eta_per_s * tau, 0.0)
        b = bound - float(phi0[0])
        if not (np.all(np.isfinite(g)) and np.isfinite(b)):
            return self._brake(q_dot, q_ddot, "non-finite constraint"), d, d_dot, d_ddot, phi_k
        da_nom = tau * u0  # a_0 - q''_k
        viol = float(g @ da_nom) - b
        active = viol > 0.0
        gg = float(g @ g)
        if active and gg <= 0.0:
            return self._brake(q_dot, q_ddot, "infeasible projection"), d, d_dot, d_ddot, phi_k
        da = da_nom - (viol / gg) * g if active else da_nom
        u_raw = da / tau
        lo, hi = self.jerk_box(q_dot, q_ddot, tau)
        u = np.clip(u_raw, lo, hi)
        saturated = bool(np.any(u != u_raw))
        self.stats["saturated"] += int(saturated)
        self.stats["active"] += int(active)
        res = JssaResult(jerk=u, phi=0.0, active=active, fallback=False)
        res.reason = "jerk saturated" if saturated else ""
        return res, d, d_dot, d_ddot, phi_k
