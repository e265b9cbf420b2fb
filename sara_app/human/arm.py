"""Pereira's over-approximative 3-DOF arm model (Pereira & Althoff 2016 Sec. III-B).

Each arm is a kinematic chain at the shoulder: two orthogonal revolute joints and a prismatic
extension that reaches the middle of the forearm. In the torso frame (z: pelvis to neck,
x: left to right shoulder, y = z x x: forward) the coordinates of the mid-forearm point m are

- theta: polar angle of m - S from the *medial* axis (pointing into the body). The medial
  direction is the one an arm can hardly point to, so the parameterisation's singularity sits
  where arms rarely are (a lateral arm held straight out sideways is the opposite pole);
- phi: azimuth about the medial axis, 0 = down, pi/2 = forward;
- r: |m - S|.

Reachable joint intervals over [0, tau] from three models, intersected (Pereira & Althoff 2016):
position limits (theta limits; r <= upper arm + half forearm), velocity limits, acceleration limits
(when joint velocities are given). Then the Cartesian enclosure: the set of directions is enclosed
by a cone around the central direction of half angle
alpha = dtheta/2 + dphi/2 * max(sin theta) (a path along a meridian and a parallel bounds the
great-circle distance), widened by the base rotation (0.1 rad/s in the paper); the arm, i.e. the
convex hull of the shoulder ball and the forearm ball (radius half forearm + the largest limb
half thickness) over all such m, lies in one capsule from S along the cone axis. Its radius then
grows by delta_y (shoulder position) and the shoulder's translation v_max tau (Pereira & Althoff
2016: ISO 13855's 2 m/s). Body parts other than the arms come from the ISO 13855 model, as in
Pereira & Althoff 2016.

Named conservative shortcuts: the [t_a, t_b] interval uses the [0, t_b] joint hull; the torso
frame is taken from the measurement (its error is part of the base-rotation allowance).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from sara_app.human.occupancy import Occupancy
from sara_app.human.params import ArmModelParams, ReachParams
from sara_app.human.skeleton import Skeleton


class _Reach(Protocol):
    """What the arm model takes from :class:`sara_app.human.reach.HumanReach`: its parameters,
    skeleton and ISO 13855 capsules (for the body parts other than the arms)."""

    params: ReachParams
    skeleton: Skeleton

    def iso13855(self, y: np.ndarray, t_end_s: np.ndarray) -> Occupancy: ...


ARMS = ("l_arm", "r_arm")
_TINY = 1e-9


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), _TINY)


def torso_frame(y: np.ndarray, idx: dict[str, int]) -> np.ndarray:
    """Rotation ``(H, 3, 3)`` whose columns are the torso axes x (right), y (fwd), z (up)."""
    z = _unit(y[:, idx["neck"]] - y[:, idx["pelvis"]])
    across = y[:, idx["r_shoulder"]] - y[:, idx["l_shoulder"]]
    x = _unit(across - np.sum(across * z, axis=-1, keepdims=True) * z)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def _arm_joints(y: np.ndarray, idx: dict[str, int], side: str) -> tuple[np.ndarray, ...]:
    s = "l" if side == "l_arm" else "r"
    return y[:, idx[f"{s}_shoulder"]], y[:, idx[f"{s}_elbow"]], y[:, idx[f"{s}_wrist"]]


def arm_coordinates(y: np.ndarray, idx: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """Joint coordinates ``(H, 2, 3)`` = (phi, theta, r) per arm and medial axes ``(H, 2, 3)``."""
    R = torso_frame(y, idx)
    q = np.empty(y.shape[:1] + (2, 3))
    medial = np.empty(y.shape[:1] + (2, 3))
    for i, side in enumerate(ARMS):
        S, E, W = _arm_joints(y, idx, side)
        d = 0.5 * (E + W) - S
        local = np.einsum("hji,hj->hi", R, d)  # components in the torso frame
        sign = 1.0 if side == "l_arm" else -1.0  # medial: +x for the left arm, -x for the right
        mx, fy, uz = sign * local[:, 0], local[:, 1], local[:, 2]
        r = np.linalg.norm(local, axis=-1)
        q[:, i, 0] = np.arctan2(fy, -uz)
        q[:, i, 1] = np.arccos(np.clip(mx / np.maximum(r, _TINY), -1.0, 1.0))
        q[:, i, 2] = r
        medial[:, i] = sign * R[:, :, 0]
    return q, medial


def frame_error(y: np.ndarray, idx: dict[str, int], delta_y_m: float) -> np.ndarray:
    """Bound ``(H,)`` on the angle between the measured and the true torso frame.

    z comes from neck - pelvis (each off by delta_y): off by beta_z = asin(2 delta_y / |n - p|);
    x from the shoulders projected normal to z: off by beta_x = asin(2 delta_y / |across|) plus
    beta_z; the frame as a whole by at most 2 beta_z + beta_x.
    """

    def ang(length: np.ndarray) -> np.ndarray:
        ratio = 2.0 * delta_y_m / np.maximum(length, _TINY)
        return np.where(ratio < 1.0, np.arcsin(np.minimum(ratio, 1.0)), np.pi)

    spine = np.linalg.norm(y[:, idx["neck"]] - y[:, idx["pelvis"]], axis=-1)
    across = np.linalg.norm(y[:, idx["r_shoulder"]] - y[:, idx["l_shoulder"]], axis=-1)
    return np.minimum(2.0 * ang(spine) + ang(across), np.pi)


def coordinate_uncertainty(
    q: np.ndarray, delta_y_m: float, frame_err: np.ndarray | None = None
) -> np.ndarray:
    """Bound ``(H, 2, 3)`` on the error of (phi, theta, r) when S, E, W are off by delta_y.

    m - S is off by at most 2 delta_y, so r by 2 delta_y and the direction by
    gamma = asin(2 delta_y / r) plus the torso frame's error ``frame_err (H,)``; theta by gamma
    and phi by gamma / min sin(theta +- gamma).
    """
    eps = 2.0 * delta_y_m
    r, theta = q[..., 2], q[..., 1]
    gamma = np.where(r > eps, np.arcsin(np.minimum(eps / np.maximum(r, _TINY), 1.0)), np.pi)
    if frame_err is not None:
        gamma = np.minimum(gamma + frame_err[:, None], np.pi)
    lo, hi = theta - gamma, theta + gamma
    min_sin = np.where((lo <= 0) | (hi >= np.pi), 0.0, np.minimum(np.sin(lo), np.sin(hi)))
    dphi = np.where(min_sin > _TINY, np.minimum(gamma / np.maximum(min_sin, _TINY), np.pi), np.pi)
    return np.stack([dphi, gamma, np.full_like(r, eps)], axis=-1)


def joint_intervals(
    q: np.ndarray,
    dq: np.ndarray,
    r_max: np.ndarray,
    tau: np.ndarray,
    arm: ArmModelParams,
    q_dot: np.ndarray | None = None,
    dq_dot: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Intersected reachable intervals over [0, tau]: ``lo, hi`` of shape ``(H, K, 2, 3)``.

    ``q, dq``: ``(H, 2, 3)`` coordinates and their error; ``r_max`` ``(H, 2)``; ``tau`` ``(K,)``.
    Where the models disagree (empty intersection: the motion broke an assumption) the hull
    of the three is used, never an empty set.
    """
    p = arm  # ArmModelParams
    t = tau[None, :, None, None]
    q0, d0 = q[:, None], dq[:, None]
    vmax = np.array([p.angle_v_max_rad_s, p.angle_v_max_rad_s, p.r_v_max_mps])
    amax = np.array([p.angle_a_max_rad_s2, p.angle_a_max_rad_s2, p.r_a_max_mps2])
    # 1st order
    lo = q0 - d0 - vmax * t
    hi = q0 + d0 + vmax * t
    # 0th order: theta and r limits (phi is unbounded)
    pos_lo = np.array([-np.inf, p.theta_min_rad, 0.0])
    pos_hi = np.broadcast_to(
        np.stack(
            [np.full_like(r_max, np.inf), np.full_like(r_max, p.theta_max_rad), r_max],
            axis=-1,
        )[:, None],
        lo.shape,
    )
    lo, hi = np.maximum(lo, pos_lo), np.minimum(hi, pos_hi)
    # 2nd order
    if q_dot is not None and dq_dot is not None:
        v_lo = (q_dot - dq_dot)[:, None]
        v_hi = (q_dot + dq_dot)[:, None]
        acc_lo = q0 - d0 + np.minimum(0.0, v_lo * t - 0.5 * amax * t**2)
        acc_hi = q0 + d0 + np.maximum(0.0, v_hi * t + 0.5 * amax * t**2)
        lo, hi = np.maximum(lo, acc_lo), np.minimum(hi, acc_hi)
    empty = lo > hi
    if np.any(empty):
        hull_lo = np.minimum(q0 - d0 - vmax * t, pos_lo)
        hull_hi = np.maximum(q0 + d0 + vmax * t, pos_hi)
        lo, hi = np.where(empty, hull_lo, lo), np.where(empty, hull_hi, hi)
    return lo, hi


def arm_occupancy(
    reach: _Reach,
    y: np.ndarray,
    t_start_s: np.ndarray,
    t_end_s: np.ndarray,
    q_dot: np.ndarray | None = None,
    dq_dot: np.ndarray | None = None,
) -> Occupancy:
    """Arm capsules from the 3-DOF model plus ISO 13855 capsules for the other body parts."""
    p: ReachParams = reach.params
    sk = reach.skeleton
    idx = {j: i for i, j in enumerate(sk.joints)}
    tau = np.asarray(t_end_s, dtype=float) + p.delay_s  # (K,)
    q, medial = arm_coordinates(y, idx)
    f_err = frame_error(y, idx, p.delta_y_m)
    dq = coordinate_uncertainty(q, p.delta_y_m, f_err)
    H, K = y.shape[0], tau.shape[0]
    ends = np.empty((H, K, 2, 2, 3))
    radius = np.empty((H, K, 2))
    R = torso_frame(y, idx)
    down, fwd = -R[:, :, 2], R[:, :, 1]  # (H, 3)
    r_max = np.empty((H, 2))
    r_fore = np.empty((H, 2))
    for i, side in enumerate(ARMS):
        S, E, W = _arm_joints(y, idx, side)
        upper = np.linalg.norm(E - S, axis=-1)
        fore = np.linalg.norm(W - E, axis=-1)
        r_max[:, i] = upper + 0.5 * fore + 3.0 * p.delta_y_m
        s = side[0]
        th = max(
            p.half_thickness_m[sk.part_index(f"{s}_hand")],
            p.half_thickness_m[sk.part_index(f"{s}_lower_arm")],
            p.half_thickness_m[sk.part_index(f"{s}_upper_arm")],
        )
        r_fore[:, i] = 0.5 * (fore + 2.0 * p.delta_y_m) + th
    lo, hi = joint_intervals(q, dq, r_max, tau, p.arm, q_dot, dq_dot)
    phi_w = hi[..., 0] - lo[..., 0]
    th_lo, th_hi = np.clip(lo[..., 1], 0.0, np.pi), np.clip(hi[..., 1], 0.0, np.pi)
    phi_c, th_c = 0.5 * (lo[..., 0] + hi[..., 0]), 0.5 * (th_lo + th_hi)
    max_sin = np.where(
        (th_lo <= 0.5 * np.pi) & (th_hi >= 0.5 * np.pi),
        1.0,
        np.maximum(np.sin(th_lo), np.sin(th_hi)),
    )
    full = phi_w >= 2.0 * np.pi
    alpha = np.where(full, th_hi, 0.5 * (th_hi - th_lo) + 0.5 * phi_w * max_sin)
    # Central direction u = cos(theta) medial + sin(theta) (cos(phi) down + sin(phi) fwd).
    m = medial[:, None]  # (H, 1, 2, 3)
    dn, fw = down[:, None, None], fwd[:, None, None]
    c = np.cos(th_c)[..., None] * m + np.sin(th_c)[..., None] * (
        np.cos(phi_c)[..., None] * dn + np.sin(phi_c)[..., None] * fw
    )
    c = np.where(full[..., None], m, c)
    # Base rotation since the measurement, and the measured frame's own error (the cone is
    # mapped to the world with the measured frame).
    alpha = alpha + p.arm.base_rotation_rad_s * tau[None, :, None] + f_err[:, None, None]
    r_hi = hi[..., 2]
    grow = p.delta_y_m + p.arm.shoulder_v_max_mps * tau[None, :, None]
    r_sh = np.stack([p.half_thickness_m[sk.part_index(f"{s[0]}_upper_arm")] for s in ARMS])
    cone = alpha < 0.5 * np.pi
    for i, side in enumerate(ARMS):
        S = _arm_joints(y, idx, side)[0][:, None]  # (H, 1, 3)
        tip = S + np.where(cone[..., i, None], r_hi[..., i, None] * c[:, :, i], 0.0)
        ends[:, :, i, 0] = S
        ends[:, :, i, 1] = tip
        spread = np.where(cone[..., i], r_hi[..., i] * np.sin(alpha[..., i]), r_hi[..., i])
        radius[:, :, i] = np.maximum(r_sh[i], spread + r_fore[:, None, i]) + grow[..., 0]
    iso = reach.iso13855(y, t_end_s)
    iso_ends = np.broadcast_to(iso.ends, (H, K) + iso.ends.shape[2:])
    iso_radius = np.broadcast_to(iso.radius, (H, K, iso.radius.shape[2]))
    keep = np.array([not n.endswith(("_arm", "_hand")) for n in sk.parts])
    names = ARMS + tuple(n for n, k in zip(sk.parts, keep) if k)
    return Occupancy(
        "arm",
        np.concatenate([ends, iso_ends[:, :, keep]], axis=2),
        np.concatenate([radius, iso_radius[:, :, keep]], axis=2),
        names,
    )
