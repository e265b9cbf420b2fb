"""Soundness of Pereira's arm model on synthetic arm motion that obeys its bounds.

Arm coordinates (phi, theta, r) move with bounded rates (constant-rate and bang-bang
acceleration profiles), the elbow sits on the circle consistent with the limb lengths, the
whole body translates at up to the shoulder speed and rotates about the vertical at up to the
base rotation rate; measurements carry noise up to delta_y. Every future shoulder, elbow and
wrist (grown by its part's half thickness) must lie in the arm's capsule.
"""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.geometry.shapes import point_segment_distance
from sara_app.human.arm import arm_coordinates, arm_occupancy
from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.skeleton import skeleton

L1, L2 = 0.30, 0.26  # upper arm, forearm


def _rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _body(phi, theta, r, swivel, side_sign):
    """Shoulder-relative elbow and wrist for one arm in the torso frame (x right, y fwd, z up).

    side_sign: +1 for the left arm (medial = +x), -1 for the right arm (medial = -x).
    """
    medial = np.array([side_sign, 0.0, 0.0])
    down, fwd = np.array([0, 0, -1.0]), np.array([0, 1.0, 0])
    u = np.cos(theta) * medial + np.sin(theta) * (np.cos(phi) * down + np.sin(phi) * fwd)
    m = r * u
    # elbow: |E| = L1, |E - m| = L2 / 2: on a circle about u
    a = (L1**2 - (L2 / 2) ** 2 + r**2) / (2 * r)
    h = np.sqrt(max(L1**2 - a**2, 0.0))
    e1 = np.cross(u, fwd if abs(u @ fwd) < 0.9 else down)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(u, e1)
    E = a * u + h * (np.cos(swivel) * e1 + np.sin(swivel) * e2)
    return E, 2 * m - E


def _skeleton_at(t, traj, v_body, w_body, sk):
    """Full skeleton (J, 3) at time t for per-arm coordinate trajectories."""
    R = _rot_z(w_body * t)
    offset = v_body * t + np.array([0, 0, 0.0])
    pts = {
        "head": (0, 0, 1.65),
        "neck": (0, 0, 1.45),
        "pelvis": (0, 0, 0.95),
        "l_hip": (-0.1, 0, 0.92),
        "r_hip": (0.1, 0, 0.92),
        "l_knee": (-0.1, 0, 0.5),
        "r_knee": (0.1, 0, 0.5),
        "l_ankle": (-0.1, 0, 0.08),
        "r_ankle": (0.1, 0, 0.08),
    }
    y = {k: np.array(v, dtype=float) for k, v in pts.items()}
    for side, sign, sx in (("l", 1.0, -0.18), ("r", -1.0, 0.18)):
        S = np.array([sx, 0, 1.42])
        phi, theta, r, swivel = traj[side](t)
        E, W = _body(phi, theta, r, swivel, sign)
        y[f"{side}_shoulder"], y[f"{side}_elbow"], y[f"{side}_wrist"] = S, S + E, S + W
    return np.array([R @ y[j] + offset for j in sk.joints])


def _arm_traj(rng, p, profile):
    q0 = np.array([rng.uniform(-np.pi, np.pi), rng.uniform(0.4, 2.6), rng.uniform(0.25, 0.40)])
    vmax = np.array([p.angle_v_max_rad_s, p.angle_v_max_rad_s, p.r_v_max_mps])
    amax = np.array([p.angle_a_max_rad_s2, p.angle_a_max_rad_s2, p.r_a_max_mps2])
    v0 = rng.uniform(-1, 1, 3) * vmax
    sign = rng.choice([-1.0, 1.0], 3)
    swivel = rng.uniform(0, 2 * np.pi)
    r_lo, r_hi = abs(L1 - L2 / 2) + 0.01, L1 + L2 / 2 - 0.001

    def f(t):
        if profile == "const":
            q = q0 + v0 * t
        else:  # accelerate at the bound toward +-vmax, then hold
            t_sat = (vmax - sign * v0) / amax
            tt = np.minimum(t, t_sat)
            q = q0 + v0 * tt + 0.5 * sign * amax * tt**2 + sign * vmax * np.maximum(t - t_sat, 0)
        q[1] = np.clip(q[1], 0.05, np.pi - 0.05)  # clipping only slows the motion
        q[2] = np.clip(q[2], r_lo, r_hi)
        return q[0], q[1], q[2], swivel

    return f, v0


@pytest.mark.parametrize("with_rates", [True, False])
@pytest.mark.parametrize("profile", ["const", "bang"])
@pytest.mark.parametrize("seed", range(4))
def test_arm_model_contains_bounded_arm_motion(profile: str, seed: int, with_rates: bool) -> None:
    rng = np.random.default_rng(seed)
    params = to_reach_params(load_param_set("schepp2022_table1"), "full")
    reach = HumanReach(params)
    sk = skeleton("full")
    p = params.arm
    fl, vl = _arm_traj(rng, p, profile)
    fr, vr = _arm_traj(rng, p, profile)
    traj = {"l": fl, "r": fr}
    v_body = rng.normal(size=3)
    v_body *= rng.uniform(0, p.shoulder_v_max_mps) / np.linalg.norm(v_body)
    w_body = rng.uniform(-1, 1) * p.base_rotation_rad_s
    t_start = np.array([0.0, 0.02, 0.1])
    t_end = np.array([0.02, 0.1, 0.25])
    y0 = _skeleton_at(0.0, traj, v_body, w_body, sk)
    noise = rng.normal(size=y0.shape)
    noise *= params.delta_y_m * rng.random((len(y0), 1)) / np.linalg.norm(noise, axis=1)[:, None]
    y_meas = (y0 + noise)[None]
    # joint rates with an honest error bound (the motion's own initial rates, +-20 %)
    q_dot = np.stack([vl, vr])[None]
    dq_dot = 0.2 * np.abs(q_dot) + 0.5
    if not with_rates:  # position and velocity sub-models only
        q_dot = dq_dot = None
    occ = arm_occupancy(reach, y_meas, t_start, t_end, q_dot, dq_dot)
    idx = {j: i for i, j in enumerate(sk.joints)}
    for k in range(len(t_start)):
        for t in np.linspace(t_start[k], t_end[k], 25) + params.delay_s:
            y = _skeleton_at(t, traj, v_body, w_body, sk)
            for a, side in enumerate("lr"):
                for joint, part in (
                    ("shoulder", "upper_arm"),
                    ("elbow", "lower_arm"),
                    ("wrist", "hand"),
                ):
                    pt = y[idx[f"{side}_{joint}"]]
                    d = point_segment_distance(pt, occ.ends[0, k, a])
                    margin = params.half_thickness_m[sk.part_index(f"{side}_{part}")]
                    assert d + margin <= occ.radius[0, k, a] + 1e-12, (side, joint, k, t)


def test_arm_coordinates_round_trip() -> None:
    sk = skeleton("full")
    rng = np.random.default_rng(3)
    for _ in range(20):
        phi, theta, r = rng.uniform(-3, 3), rng.uniform(0.2, 2.9), rng.uniform(0.2, 0.4)
        traj = {s: (lambda t, q=(phi, theta, r): (*q, 0.7)) for s in "lr"}
        y = _skeleton_at(0.0, traj, np.zeros(3), 0.0, sk)[None]
        q, _ = arm_coordinates(y, {j: i for i, j in enumerate(sk.joints)})
        np.testing.assert_allclose(q[0, :, 1:], [[theta, r], [theta, r]], atol=1e-9)
        dphi = (q[0, :, 0] - phi + np.pi) % (2 * np.pi) - np.pi
        np.testing.assert_allclose(dphi, 0.0, atol=1e-9)
