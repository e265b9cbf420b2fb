"""Robot occupancy along a sampled joint trajectory: one capsule per link and time interval.

Input: samples ``t_0 < ... < t_K`` (s), configurations ``q (K+1, n)`` (rad) and, per interval
``[t_k, t_k+1]``, a rigorous joint speed bound ``qd_bound (K, n)``: ``|q_dot_j(t)| <=
qd_bound[k, j]`` for every ``t`` in the interval. Output: per interval and link a capsule that
contains the link's capsule (:attr:`RobotModel.radius_m`, fitted to the collision geometry) at
EVERY time of the interval, not only at the samples. No acceleration bound is guessed and no
difference of speed norms is used (DESIGN.md section 6): the only motion input is ``qd_bound``.

Lipschitz constants. Every joint must be revolute (checked at construction). A point ``x`` of
link ``i`` moves with ``x_dot = sum_j q_dot_j * (a_j x (x - o_j))`` over the joints ``j`` that
carry link ``i`` (``a_j`` unit axis, ``o_j`` a point on it), so ``|x_dot| <= sum_j |q_dot_j|
dist(x, axis_j)``. ``L[i, j]`` bounds ``dist(x, axis_j)`` over all points of the capsule and ALL
configurations, from the kinematic chain ``j = c_0, c_1, ..., c_p = m`` (``m`` the joint that
carries link ``i``), by the triangle inequality::

    L[i, j] = |perp_j(t_c1)| + |t_c2| + ... + |t_cp| + max_e |e_m| + r_i        (j < m)
    L[i, m] = max_e |perp_m(e_m)| + r_i

``t_c`` is joint ``c``'s origin in its parent joint's frame (a constant of the model), ``perp_j``
its component normal to axis ``j`` (also constant: ``t_c1`` is fixed in joint ``j``'s moving
frame, and the axis is too), ``e_m`` the capsule ends in joint ``m``'s frame. The distance to a
line is convex, so its maximum over the capsule is at an end ball. ``L[i, j] = 0`` for joints
that do not carry link ``i``.

Interval capsule (``bound="lipschitz"``, the default). Let ``P[k, i] = dt_k * sum_j L[i, j] *
qd_bound[k, j]``: no point of link ``i`` travels a path longer than ``P`` during the interval.
Take a point ``x`` of the link capsule, ``x = a(s) + w`` in the link's frame (``a(s)`` the axis
point at parameter ``s``, ``|w| <= r``). At the samples ``x_k = a_k(s) + R_k w`` and ``x_k+1 =
a_k+1(s) + R_k+1 w``. At any ``t`` of the interval ``|x(t) - x_k| + |x(t) - x_k+1| <= P`` (the two
pieces of the path), so ``|x(t) - (x_k + x_k+1) / 2| <= P / 2`` (triangle inequality; the point
lies in the ellipsoid with foci ``x_k, x_k+1``). The midpoint is ``(a_k(s) + a_k+1(s)) / 2 + (R_k
w + R_k+1 w) / 2``; its first term is the point at parameter ``s`` of the MID AXIS (the segment
between the midpoints of corresponding capsule ends; the axis point is affine in ``s``) and the
second has norm ``<= r``. Hence::

    ends[k, i]   = (ends_i(t_k) + ends_i(t_k+1)) / 2
    radius[k, i] = r_i + P[k, i] / 2 + ROUNDING_SLACK_M

contains the link over the whole interval.

The conservative shortcut (the usual construction; NOT what is returned): enclose the link
capsules at ``t_k`` and ``t_k+1`` (:func:`sara_app.geometry.shapes.capsule_enclosing_capsules`: the
same mid axis, radius ``r + h`` with ``h`` half the larger end displacement), then grow the radius
by ``P / 2`` (every ``t`` is within ``dt / 2`` of a sample, and a point is within ``(t - t_k) P /
dt`` of its position at ``t_k`` and within ``(t_k+1 - t) P / dt`` of its position at ``t_k+1``):
radius ``r + h + P / 2``. Sound, but the displacement is counted twice: an end moves by at most
``P``, so ``h <= P / 2``, and the ellipsoid argument above needs no ``h``. The returned capsule
has the same axis and a radius smaller by ``h``. :meth:`RobotOccupancy.added_radius` returns
``P / 2``, the enlargement over the link's own radius. Measured (tests/test_robot_occupancy.py,
random 1 ms intervals at up to half the velocity limits): ``P / 2`` is 1.0 mm on average (2.7 mm
at most) for the Panda and 1.2 mm (3.1 mm) for the UR5e; the shortcut would add ``h`` = 0.16 mm
(0.75 mm) and 0.23 mm (1.04 mm) on top. At half the velocity limits on every joint, 1 ms:
2.6 mm (Panda hand), 2.7 mm (UR5e wrist 3).

``bound="local"``: the same capsule, with ``L[i, j]`` replaced by a configuration-dependent
bound of the distance to axis ``j`` over the interval. ``d_ij(t_k)`` (the largest distance of the
capsule from axis ``j`` at the sample, exact from forward kinematics) changes at a rate of at
most ``G_ij = sum_(j' after j on the chain) L[i, j'] qd_bound[k, j']`` (only the joints after
``j`` move the link relative to axis ``j``, and the distance is 1-Lipschitz in the point), so
``d_ij(t) <= min(d_ij(t_k) + (t - t_k) G_ij, d_ij(t_k+1) + (t_k+1 - t) G_ij, L_ij)``; the minimum
of the two lines is below their mean, ``(d_ij(t_k) + d_ij(t_k+1) + dt G_ij) / 2``, so::

    P[k, i] = dt_k sum_j qd_bound[k, j] min(L[i, j], (d_ij(t_k) + d_ij(t_k+1) + dt_k G_ij) / 2)

On random motions about three quarters of the Lipschitz enlargement (down to a third); costs one
evaluation of the distances of all capsule ends to all joint axes per sample.

Forward kinematics (Rodrigues products along the joint chain, all samples), the capsule ends and
the Lipschitz interval capsules are one compiled pass (:mod:`sara_app.robot.occupancy_kernels`,
checked against pinocchio at construction); :meth:`RobotOccupancy.intervals` has no Python loop.
"""

from __future__ import annotations

import math
from typing import Any, Literal, cast

import numpy as np
import pinocchio as pin

from sara_app.errors import InputError, ParameterError, RobotModelError
from sara_app.robot.model import RobotModel
from sara_app.robot.occupancy_kernels import ends_kernel, fk_kernel, intervals_kernel

__all__ = ["ROUNDING_SLACK_M", "Bound", "RobotOccupancy"]

Bound = Literal["lipschitz", "local"]

ROUNDING_SLACK_M = 1e-9
"""Added to every interval radius to absorb floating-point rounding of the axis and the bound."""

_FK_CHECK_TOL_M = 1e-9


def _skew(a: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


class RobotOccupancy:
    """Link capsules over the time intervals of a sampled joint trajectory, for one robot.

    Built once per :class:`RobotModel` (precomputes the chain, the Lipschitz matrix
    :attr:`lipschitz` ``(L, n)`` in m/rad and scratch buffers). Not thread-safe (scratch buffers).
    """

    def __init__(self, model: RobotModel) -> None:
        pm = model.pin_model
        n = model.n_dof
        n_links = model.n_links
        if pm.njoints != n + 1:
            raise RobotModelError(f"{model.name}: {pm.njoints - 1} joints for {n} dof")
        data = pm.createData()
        q0 = pin.neutral(pm)
        pin.computeJointJacobians(pm, data, q0)
        axes = np.zeros((n, 3))
        q_index = np.zeros(n, dtype=np.intp)
        for jid in range(1, pm.njoints):
            J = pin.getJointJacobian(pm, data, jid, pin.ReferenceFrame.LOCAL)
            col = np.reshape(np.array(J), (6, -1))[:, pm.idx_vs[jid]]
            lin, ang = col[:3], col[3:]
            if np.linalg.norm(lin) > 1e-12 or abs(np.linalg.norm(ang) - 1.0) > 1e-9:
                raise RobotModelError(
                    f"joint {pm.names[jid]!r} ({pm.joints[jid].shortname()}) is not a revolute "
                    "joint about an axis through its frame origin; RobotOccupancy supports "
                    "revolute joints only"
                )
            axes[jid - 1] = ang / np.linalg.norm(ang)
            q_index[jid - 1] = pm.idx_qs[jid]
        parents = np.array([pm.parents[j] for j in range(1, pm.njoints)], dtype=np.intp)
        Rp = np.array([pm.jointPlacements[j].rotation for j in range(1, pm.njoints)])
        tp = np.array([pm.jointPlacements[j].translation for j in range(1, pm.njoints)])
        K = np.array([_skew(a) for a in axes])
        # placement @ Rot(axis, q) = N0 + sin(q) N1 + (1 - cos(q)) N2 (Rodrigues), as flattened
        # 4x4 matrices: N0 = [Rp tp; 0 1], N1 = [Rp K 0; 0 0], N2 = [Rp K^2 0; 0 0].
        N = np.zeros((n, 3, 4, 4))
        N[:, 0, :3, :3] = Rp
        N[:, 0, :3, 3] = tp
        N[:, 0, 3, 3] = 1.0
        N[:, 1, :3, :3] = Rp @ K
        N[:, 2, :3, :3] = Rp @ K @ K
        self._N = N.reshape(n, 3, 16)
        self._parents = np.asarray(parents, dtype=np.int64)
        self._q_index = q_index
        self._q_identity = bool(np.array_equal(q_index, np.arange(n)))
        self._axes = axes

        # Capsule ends in the frame of the joint that carries each link.
        link_joint = np.zeros(n_links, dtype=np.intp)
        ends_joint = np.zeros((n_links, 2, 3))
        for i, fid in enumerate(model._frame_ids):
            frame = pm.frames[fid]
            link_joint[i] = frame.parentJoint
            R, p = frame.placement.rotation, frame.placement.translation
            ends_joint[i] = model.capsules_local[i] @ R.T + p
        self._link_joint = link_joint.astype(np.int64)
        self._ends_joint = ends_joint
        radius = np.array(model.radius_m, dtype=float)

        # after[i, j, j']: joint j' carries link i and lies after joint j on its chain (j' moves
        # link i relative to axis j); joints are 0-based here.
        after = np.zeros((n_links, n, n), dtype=bool)
        L = np.zeros((n_links, n))
        for i in range(n_links):
            m = int(link_joint[i])
            if m == 0:
                continue
            chain = [int(j) for j in pm.supports[m]][1:]  # joint ids from the base to m
            e_norm = float(np.max(np.linalg.norm(ends_joint[i], axis=1)))
            for pos, j in enumerate(chain):
                for jj in chain[pos + 1 :]:
                    after[i, j - 1, jj - 1] = True
                a = axes[j - 1]
                if j == m:
                    e = ends_joint[i]
                    perp = e - np.outer(e @ a, a)
                    L[i, j - 1] = float(np.max(np.linalg.norm(perp, axis=1))) + radius[i]
                    continue
                t1 = tp[chain[pos + 1] - 1]
                length = float(np.linalg.norm(t1 - (t1 @ a) * a))
                length += sum(float(np.linalg.norm(tp[c - 1])) for c in chain[pos + 2 :])
                L[i, j - 1] = length + e_norm + radius[i]
        L.flags.writeable = False
        self.lipschitz: np.ndarray = L
        """``(L, n)``: bound of the distance from joint j's axis to link i's capsule, any q (m)."""
        # G[k, j, i] = sum_j' after[i, j, j'] L[i, j'] qd[k, j'] = (qd @ W_flat)[k, j L + i].
        W = after * L[:, None, :]  # (L, n, n')
        self._W_flat = np.ascontiguousarray(W.transpose(2, 1, 0).reshape(n, n * n_links))
        self._lipschitz_T = np.ascontiguousarray(L.T)
        self.model = model
        self.n_dof = n
        self.n_links = n_links
        radius.flags.writeable = False
        self.radius_m: np.ndarray = radius
        self._radius0 = radius + ROUNDING_SLACK_M
        self._T0 = np.array(model.T_world_base, dtype=float)
        self._capacity = 0
        self._ensure_capacity(32)
        self._check_fk(np.random.default_rng(0))

    # -- buffers and forward kinematics --------------------------------------------------------

    def _ensure_capacity(self, S: int) -> None:
        if S <= self._capacity:
            return
        n = self.n_dof
        self._capacity = S
        # World poses of the joint frames (index 0: the base), the local joint transforms
        # placement @ Rot(axis, q) and their coefficients (1, sin q, 1 - cos q).
        # World poses of the joint frames (index 0: the base; row 3 stays [0, 0, 0, 1]).
        self._H = np.zeros((S, n + 1, 4, 4))
        self._H[:, :, 3, 3] = 1.0
        self._H[:, 0] = self._T0
        self._E = np.empty((S, self.n_links, 2, 3))

    def kernel_arrays(self) -> tuple[np.ndarray, ...]:
        """The constants of the compiled kinematics, for kernels that call
        :func:`~sara_app.robot.occupancy_kernels.fk_kernel` and ``ends_kernel`` themselves:
        ``(q_index (n,) int64, N (n, 3, 16), parents (n,), link_joint (L,), ends_joint (L, 2,
        3), axes (n, 3), T_world_base (4, 4))`` (``q_index`` maps joint order to ``q``)."""
        return (
            self._q_index.astype(np.int64), self._N, self._parents, self._link_joint,
            self._ends_joint, self._axes, self._T0,
        )  # fmt: skip

    def interval_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lipschitz (L, n), radius0 (L,))`` as
        :func:`~sara_app.robot.occupancy_kernels.intervals_kernel` takes them (the capsule
        radius per interval is ``dt / 2 * lipschitz @ v_bound + radius0``)."""
        return self.lipschitz, self._radius0

    def plan_arrays(self, margin_m: np.ndarray) -> tuple[np.ndarray, ...]:
        """The occupancy per interval as the compiled shield cycles plan it
        (:data:`~sara_app.robot.shielded_kernels.OCCUPANCY`): ``(q_index, N, parents,
        link_joint, ends_joint, lipschitz, radius0, T_world_base (4, 4), margin_m (L,))``, the
        tracking margin ``margin_m`` added to every capsule's radius."""
        q_index, N, parents, link_joint, ends_joint, _axes, T0 = self.kernel_arrays()
        margin = np.asarray(margin_m, dtype=np.float64)
        return (q_index, N, parents, link_joint, ends_joint, self.lipschitz, self._radius0,
                np.asarray(T0, dtype=np.float64), margin)  # fmt: skip

    def _fk(self, Q: np.ndarray) -> np.ndarray:
        """World poses ``(S, n+1, 4, 4)`` of the joint frames (index 0: the base), a view into
        the scratch buffer (valid until the next call)."""
        S = Q.shape[0]
        self._ensure_capacity(S)
        H = self._H[:S]
        fk_kernel(Q if self._q_identity else Q[:, self._q_index], self._N, self._parents, H)
        return H

    def _ends(self, H: np.ndarray) -> np.ndarray:
        """World capsule ends ``(S, L, 2, 3)`` from joint poses ``(S, n+1, 4, 4)`` (a scratch
        buffer, valid until the next call)."""
        E = self._E[: H.shape[0]]
        ends_kernel(H, self._link_joint, self._ends_joint, E, H.shape[0])
        return E

    def link_ends(self, q: np.ndarray) -> np.ndarray:
        """World-frame capsule ends ``(S, L, 2, 3)`` at configurations ``q (S, n)``.

        Same result as :meth:`RobotModel.link_capsules_batch` (vectorised numpy kinematics).
        """
        Q = self._check_q(q, "q")
        return self._ends(self._fk(Q)).copy()

    def _check_fk(self, rng: np.random.Generator) -> None:
        lim = self.model.limits
        Q = rng.uniform(lim.q_min, lim.q_max, size=(3, self.n_dof))
        Q[0] = 0.0
        ours = self.link_ends(Q)
        ref = self.model.link_capsules_batch(Q)
        # also the first-call dispatch of the interval kernel, here rather than in a control loop
        self.intervals(Q[:2], np.zeros((1, self.n_dof)), np.array([0.0, 0.01]))
        err = float(np.max(np.abs(ours - ref)))
        if not err <= _FK_CHECK_TOL_M:
            raise RobotModelError(
                f"{self.model.name}: vectorised kinematics differ from pinocchio by {err:.3g} m; "
                "the joint model is not supported by RobotOccupancy"
            )

    # -- validation ----------------------------------------------------------------------------

    def _check_q(self, q: np.ndarray, what: str) -> np.ndarray:
        Q = np.asarray(q, dtype=float)
        if Q.ndim != 2 or Q.shape[1] != self.n_dof:
            raise InputError(
                f"{what} has shape {Q.shape}; expected (S, {self.n_dof}) joint positions (rad) "
                f"for {self.model.name}"
            )
        if not math.isfinite(float(Q.sum())):  # one reduction; NaN or inf anywhere shows
            bad = np.argwhere(~np.isfinite(Q))[0]
            raise InputError(
                f"{what}[{bad[0]}, {bad[1]}] = {Q[bad[0], bad[1]]}; expected finite values"
            )
        return Q

    def _check(
        self, q: np.ndarray, qd_bound: np.ndarray, t: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        Q = self._check_q(q, "q")
        if Q.shape[0] < 2:
            raise InputError(
                f"q has {Q.shape[0]} sample(s); expected at least 2 (one interval) as (K+1, "
                f"{self.n_dof})"
            )
        V, dt = self._check_bounds(qd_bound, t, Q.shape[0] - 1, "the samples in q")
        return Q, V, dt

    def _check_bounds(
        self, qd_bound: np.ndarray, t: np.ndarray, K: int | None, source: str
    ) -> tuple[np.ndarray, np.ndarray]:
        """Checked ``qd_bound (K, n)`` and ``dt (K,)``; ``K=None`` takes it from ``t``."""
        T = np.asarray(t, dtype=float)
        if K is None:
            K = T.shape[0] - 1 if T.ndim == 1 else -1
            if K < 1:
                raise InputError(f"t has shape {T.shape}; expected (K+1,) with K >= 1 intervals")
        if T.shape != (K + 1,):
            raise InputError(
                f"t has shape {T.shape}; expected ({K + 1},): one time (s) per {source}"
            )
        if not math.isfinite(float(T.sum())):
            i = int(np.flatnonzero(~np.isfinite(T))[0])
            raise InputError(f"t[{i}] = {T[i]}; expected finite times (s)")
        dt = T[1:] - T[:-1]
        if not float(dt.min()) > 0.0:
            i = int(np.flatnonzero(~(dt > 0.0))[0])
            raise InputError(
                f"t is not strictly increasing: t[{i}] = {T[i]} and t[{i + 1}] = {T[i + 1]}; "
                "expected t_0 < t_1 < ... < t_K"
            )
        V = np.asarray(qd_bound, dtype=float)
        if V.shape != (K, self.n_dof):
            raise InputError(
                f"qd_bound has shape {V.shape}; expected ({K}, {self.n_dof}): one joint speed "
                f"bound (rad/s) per joint and interval between {source}"
            )
        if not (math.isfinite(float(V.sum())) and float(V.min()) >= 0.0):
            bad = np.argwhere(~(np.isfinite(V) & (V >= 0.0)))[0]
            raise InputError(
                f"qd_bound[{bad[0]}, {bad[1]}] = {V[bad[0], bad[1]]}; expected finite values "
                ">= 0 (rad/s)"
            )
        return V, dt

    # -- bounds --------------------------------------------------------------------------------

    def added_radius(self, qd_bound: np.ndarray, t: np.ndarray) -> np.ndarray:
        """``P / 2 = dt_k / 2 * sum_j L[i, j] qd_bound[k, j]`` ``(K, L)`` (m): the Lipschitz
        enlargement of every link radius (interval radius minus link radius, less the slack)."""
        V, dt = self._check_bounds(qd_bound, t, None, "sample")
        return (0.5 * dt)[:, None] * (V @ self.lipschitz.T)

    def _half_path_local(
        self, H: np.ndarray, E: np.ndarray, V: np.ndarray, dt: np.ndarray
    ) -> np.ndarray:
        """Configuration-dependent ``P / 2`` ``(K, L)``, see the module docstring."""
        S, n, L = H.shape[0], self.n_dof, self.n_links
        u = H[:, 1:, :3, :3] @ self._axes[:, :, None]  # (S, n, 3, 1) world joint axes
        # dist(x, axis j) = |u_j x (x - o_j)| = |[u_j]x x - [u_j]x o_j|, with the skew matrices
        # applied to all capsule ends in one product per sample (no cancellation: no squares of
        # large coordinates are subtracted).
        C = np.zeros((S, n, 3, 3))
        u0, u1, u2 = u[:, :, 0, 0], u[:, :, 1, 0], u[:, :, 2, 0]
        C[:, :, 0, 1] = -u2
        C[:, :, 0, 2] = u1
        C[:, :, 1, 0] = u2
        C[:, :, 1, 2] = -u0
        C[:, :, 2, 0] = -u1
        C[:, :, 2, 1] = u0
        Cx = C.reshape(S, 3 * n, 3) @ E.reshape(S, 2 * L, 3).transpose(0, 2, 1)  # (S, 3n, 2L)
        diff = Cx.reshape(S, n, 3, 2 * L) - C @ H[:, 1:, :3, 3:]
        perp2 = np.einsum("snck,snck->snk", diff, diff).reshape(S, n, L, 2)
        # The distance to a line is convex: its maximum over a capsule is at an end ball.
        d = np.sqrt(np.maximum(perp2[..., 0], perp2[..., 1]))
        d += self.radius_m  # (S, n, L)
        # lever[k, j, i] = min(L[i, j], (d(t_k) + d(t_k+1) + dt_k G[k, i, j]) / 2)
        lever = (V @ self._W_flat).reshape(S - 1, n, L)
        lever *= dt[:, None, None]
        lever += d[:-1]
        lever += d[1:]
        lever *= 0.5
        np.minimum(self._lipschitz_T, lever, out=lever)  # L = 0 where joint j does not move i
        return (0.5 * dt)[:, None] * (V[:, None, :] @ lever)[:, 0, :]

    # -- occupancy -----------------------------------------------------------------------------

    def intervals(
        self,
        q: np.ndarray,
        qd_bound: np.ndarray,
        t: np.ndarray,
        *,
        bound: Bound = "lipschitz",
    ) -> tuple[np.ndarray, np.ndarray]:
        """Capsules containing each link over each interval: ``(ends (K, L, 2, 3), radius (K, L))``.

        ``q (K+1, n)`` rad, ``qd_bound (K, n)`` rad/s (``|q_dot_j| <= qd_bound[k, j]`` on
        ``[t_k, t_k+1]``), ``t (K+1,)`` s strictly increasing. ``bound``: ``"lipschitz"``
        (configuration-independent constants, the default) or ``"local"`` (tighter, from the
        distances to the joint axes at the samples). Raises :class:`InputError` for bad inputs.
        """
        if bound not in ("lipschitz", "local"):
            raise ParameterError(f"bound = {bound!r}; valid choices: lipschitz, local")
        Q = np.asarray(q, dtype=float)
        V = np.asarray(qd_bound, dtype=float)
        T = np.asarray(t, dtype=float)
        S = Q.shape[0] if Q.ndim == 2 else 0
        n = self.n_dof
        if S < 2 or Q.shape[1] != n or V.shape != (S - 1, n) or T.shape != (S,):
            self._check(Q, V, T)  # raises with the shape that is wrong
        if S > self._capacity:
            self._ensure_capacity(S)
        ends = np.empty((S - 1, self.n_links, 2, 3))
        radius = np.empty((S - 1, self.n_links))
        Qj = Q if self._q_identity else Q[:, self._q_index]
        status = intervals_kernel(
            Qj, V, T, self._N, self._parents, self._link_joint, self._ends_joint,
            self.lipschitz, self._radius0, self._H, self._E, ends, radius,
        )  # fmt: skip
        if status:
            self._check(Q, V, T)  # raises with the value that is wrong
            raise InputError(f"trajectory rejected by the occupancy kernel (code {status})")
        if bound == "local":
            H, E = self._H[:S], self._E[:S]
            radius = self._half_path_local(H, E, V, T[1:] - T[:-1]) + self._radius0
        return ends, radius

    def intervals_of(
        self, trajectory: object, *, bound: Bound = "lipschitz"
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`intervals` of a sampled trajectory object with arrays ``times (K+1,)``,
        ``q (K+1, n)`` and ``v_bound (K, n)`` (e.g. ``sara_app.robot.shielded.ShieldedTrajectory``,
        whose ``v_bound`` is a rigorous per-interval bound on ``|q_dot|``)."""
        traj = cast(Any, trajectory)
        try:
            q, v_bound, times = traj.q, traj.v_bound, traj.times
        except AttributeError:
            missing = [a for a in ("times", "q", "v_bound") if not hasattr(trajectory, a)]
            if not missing:
                raise
            raise InputError(
                f"trajectory {type(trajectory).__name__} has no {', '.join(missing)}; expected "
                "arrays times (K+1,), q (K+1, n) and v_bound (K, n)"
            ) from None
        return self.intervals(q, v_bound, times, bound=bound)

    def swept(
        self,
        q: np.ndarray,
        qd_bound: np.ndarray,
        t: np.ndarray,
        *,
        bound: Bound = "lipschitz",
    ) -> tuple[np.ndarray, np.ndarray]:
        """One capsule per link containing all its interval capsules: ``(ends (L, 2, 3),
        radius (L,))``, for display.

        Axis: the centres of the bounding boxes of corresponding interval ends; radius: the
        largest end distance plus interval radius (a point at parameter ``s`` of an interval
        axis is at most the larger end distance from the new axis at ``s``). Where a single
        ball around all interval ends is smaller, that ball is returned (coincident ends).
        """
        ends, radius = self.intervals(q, qd_bound, t, bound=bound)
        axis = 0.5 * (ends.min(axis=0) + ends.max(axis=0))  # (L, 2, 3)
        r_caps = (np.linalg.norm(ends - axis, axis=-1).max(axis=-1) + radius).max(axis=0)
        pts = ends.transpose(1, 0, 2, 3).reshape(self.n_links, -1, 3)  # (L, 2K, 3)
        centre = 0.5 * (pts.min(axis=1) + pts.max(axis=1))  # (L, 3)
        r_ball = (np.linalg.norm(ends - centre[None, :, None], axis=-1).max(axis=-1) + radius).max(
            axis=0
        )
        use_ball = r_ball < r_caps
        out = np.where(use_ball[:, None, None], centre[:, None, :], axis)
        return out, np.where(use_ball, r_ball, r_caps)
