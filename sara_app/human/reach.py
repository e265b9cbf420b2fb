"""Human reachable occupancy as capsules: SaRA's R_POS, R_VEL, R_ACC (seed 001 Sec. II-B) and the
ISO 13855 expansion model (seed 000 Sec. III-A); Pereira's arm model lives in ``arm.py``.

Time: every set is for an interval ``[t_start, t_end]`` of time *since the measurement's time
stamp*; the caller passes the age of the measurement inside those times (command time minus
measurement time) and the models add the sensor delay, so every term grows with
age + delay + horizon. All models are vectorised over humans ``H`` and intervals ``K``:

- joint positions ``y`` ``(H, J, 3)`` m, velocities ``v`` ``(H, J, 3)`` m/s and their error bound
  ``dv`` ``(H, J)`` m/s (sensor's delta_y' or the estimator's bound, see ``velocity.py``);
- outputs ``ends`` ``(H, K, C, 2, 3)`` and ``radius`` ``(H, K, C)``, C capsules per model.

Soundness conditions of each model (what the parameters must bound) are stated per method.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sara_app.errors import InputError, UnknownNameError
from sara_app.geometry import ball_enclosing_balls
from sara_app.human.params import ReachParams
from sara_app.human.skeleton import skeleton

MODELS: tuple[str, ...] = ("pos", "vel", "acc", "iso13855", "arm")
SARA_MODELS: tuple[str, ...] = ("pos", "vel", "acc")


@dataclass
class Occupancy:
    """Capsules of one model: ``ends (H, K, C, 2, 3)``, ``radius (H, K, C)``, names ``(C,)``."""

    model: str
    ends: np.ndarray
    radius: np.ndarray
    names: tuple[str, ...]


def check_intervals(t_start_s: np.ndarray, t_end_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Validate interval arrays ``(K,)``: finite, 0 <= start <= end."""
    t_start_s = np.atleast_1d(np.asarray(t_start_s, dtype=float))
    t_end_s = np.atleast_1d(np.asarray(t_end_s, dtype=float))
    if t_start_s.shape != t_end_s.shape or t_start_s.ndim != 1:
        raise InputError(
            f"interval starts {t_start_s.shape} and ends {t_end_s.shape} must be equal (K,) arrays"
        )
    if not (np.all(np.isfinite(t_start_s)) and np.all(np.isfinite(t_end_s))):
        raise InputError("interval times must be finite")
    if np.any(t_start_s < 0) or np.any(t_end_s < t_start_s):
        raise InputError(
            f"intervals must satisfy 0 <= start <= end; got starts {t_start_s.tolist()} "
            f"and ends {t_end_s.tolist()}"
        )
    return t_start_s, t_end_s


class HumanReach:
    """All reachability models for one skeleton kind and parameter set; tables built once."""

    def __init__(self, params: ReachParams) -> None:
        self.params = params
        self.skeleton = sk = skeleton(params.kind)
        self.ja = sk.part_joints[:, 0]
        self.jb = sk.part_joints[:, 1]
        self.is_ball = self.ja == self.jb
        p = params
        # R_POS: one ball per limb, then head and torso from R_VEL (the seed's four balls leave
        # the head and torso uncovered; a verdict "POS is free" must cover the whole human).
        self.limb_root = np.array([c[0] for c in sk.limb_chains], dtype=int)
        self.limb_pos_parts = np.array([sk.part_index(n) for n in ("head", "torso")], dtype=int)
        # Largest half thickness along each limb (tip ball and segment capsules).
        self.limb_half_th = np.array(
            [
                max(
                    p.half_thickness_m[tip],
                    *(
                        p.half_thickness_m[i]
                        for i in range(sk.n_parts)
                        if sk.part_joints[i, 0] in chain and sk.part_joints[i, 1] in chain
                    ),
                )
                for chain, tip in zip(sk.limb_chains, sk.limb_tip_parts)
            ]
        )
        self.pos_names = sk.limbs + ("head", "torso")
        self.part_names = sk.parts
        self.coverage = {m: self._coverage(m) for m in MODELS}

    def _coverage(self, model: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Which joints each capsule of ``model`` must contain, and with which margin.

        Returns ``(capsule, joint, margin_m)`` index arrays: joint ``joint[i]``, grown by the
        body part's half thickness ``margin_m[i]``, must lie in capsule ``capsule[i]``. Every
        joint appears at least once. Used by the containment measurements and tests.
        """
        sk, p = self.skeleton, self.params
        half = p.iso_radius_m if model in ("iso13855",) else p.half_thickness_m
        rows: list[tuple[int, int, float]] = []
        if model in ("vel", "acc", "iso13855"):
            for i, (a, b) in enumerate(sk.part_joints):
                rows += [(i, int(a), float(half[i])), (i, int(b), float(half[i]))]
        elif model == "pos":
            for i, chain in enumerate(sk.limb_chains):
                rows += [(i, j, float(self.limb_half_th[i])) for j in chain]
            for k, part in enumerate(self.limb_pos_parts):
                for j in sk.part_joints[part]:
                    rows.append((len(sk.limb_chains) + k, int(j), float(half[part])))
        elif model == "arm":
            for i, s in enumerate(("l", "r")):
                for j, part in (
                    ("shoulder", "upper_arm"),
                    ("elbow", "lower_arm"),
                    ("wrist", "hand"),
                ):
                    rows.append(
                        (i, sk.joint_index(f"{s}_{j}"), float(half[sk.part_index(f"{s}_{part}")]))
                    )
            others = [k for k, n in enumerate(sk.parts) if not n.endswith(("_arm", "_hand"))]
            for c, part in enumerate(others, start=2):
                for j in sk.part_joints[part]:
                    rows.append((c, int(j), float(p.iso_radius_m[part])))
        arr = np.array(rows)
        return arr[:, 0].astype(int), arr[:, 1].astype(int), arr[:, 2]

    # --- input validation -------------------------------------------------------------------

    def check_positions(self, y: np.ndarray) -> np.ndarray:
        """Validate joint positions: ``(H, J, 3)`` (or ``(J, 3)``, promoted), finite."""
        y = np.asarray(y, dtype=float)
        if y.ndim == 2:
            y = y[None]
        J = self.skeleton.n_joints
        if y.ndim != 3 or y.shape[1:] != (J, 3):
            raise InputError(
                f"joint positions have shape {y.shape}; expected (H, {J}, 3) for the "
                f"{self.skeleton.kind!r} skeleton ({', '.join(self.skeleton.joints)})"
            )
        bad = ~np.all(np.isfinite(y), axis=-1)
        if np.any(bad):
            h, j = np.argwhere(bad)[0]
            raise InputError(
                f"joint {self.skeleton.joints[j]!r} of human {h} is not finite: {y[h, j].tolist()}"
            )
        return y

    # --- models --------------------------------------------------------------------------------

    def vel(self, y: np.ndarray, t_end_s: np.ndarray) -> Occupancy:
        """R_VEL = y(0) + B(delta_y) + B(v_max tau) per joint, capsules per body part.

        Sound when every joint's speed stays below its v_max.
        """
        p = self.params
        tau = np.asarray(t_end_s, dtype=float) + p.delay_s  # (K,)
        r_joint = p.delta_y_m + p.v_max_mps[None, :] * tau[:, None]  # (K, J)
        radius = np.maximum(r_joint[:, self.ja], r_joint[:, self.jb]) + p.half_thickness_m
        ends = np.stack([y[:, self.ja], y[:, self.jb]], axis=2)  # (H, P, 2, 3)
        K = tau.shape[0]
        H = y.shape[0]
        return Occupancy(
            "vel",
            np.broadcast_to(ends[:, None], (H, K) + ends.shape[1:]),
            np.broadcast_to(radius[None], (H, K, radius.shape[1])),
            self.part_names,
        )

    def acc(
        self,
        y: np.ndarray,
        v: np.ndarray,
        dv: np.ndarray,
        t_start_s: np.ndarray,
        t_end_s: np.ndarray,
    ) -> Occupancy:
        """R_ACC = y(0) + B(delta_y) + v(0) tau + B(dv tau) + B(a_max tau^2 / 2) per joint.

        Over an interval the joint's balls move linearly and grow convexly, so their union is
        inside the capsule of the end balls (balls at tau_a, tau_b, radius at tau_b); body parts
        with two joints take the smallest ball enclosing each joint's two end balls. Sound when
        every joint's acceleration stays below a_max and ``dv`` bounds the velocity error.
        """
        p = self.params
        ta = np.asarray(t_start_s, dtype=float) + p.delay_s  # (K,)
        tb = np.asarray(t_end_s, dtype=float) + p.delay_s
        a_half = 0.5 * p.a_max_mps2  # (J,)
        # (H, K, J)
        ra = p.delta_y_m + dv[:, None, :] * ta[None, :, None] + a_half * (ta**2)[None, :, None]
        rb = p.delta_y_m + dv[:, None, :] * tb[None, :, None] + a_half * (tb**2)[None, :, None]
        ca = y[:, None] + v[:, None] * ta[None, :, None, None]  # (H, K, J, 3)
        cb = y[:, None] + v[:, None] * tb[None, :, None, None]
        cball, rball = ball_enclosing_balls(ca, ra, cb, rb)
        ball = self.is_ball
        ends = np.empty(y.shape[:1] + (ta.shape[0], self.skeleton.n_parts, 2, 3))
        ends[:, :, ball, 0] = ca[:, :, self.ja[ball]]
        ends[:, :, ball, 1] = cb[:, :, self.ja[ball]]
        ends[:, :, ~ball, 0] = cball[:, :, self.ja[~ball]]
        ends[:, :, ~ball, 1] = cball[:, :, self.jb[~ball]]
        radius = np.where(
            ball, rb[:, :, self.ja], np.maximum(rball[:, :, self.ja], rball[:, :, self.jb])
        )
        return Occupancy("acc", ends, radius + p.half_thickness_m, self.part_names)

    def pos(self, y: np.ndarray, t_end_s: np.ndarray) -> Occupancy:
        """R_POS: per limb a ball at its root joint (shoulder or hip) of radius
        v_root tau + sum of the measured segment lengths + the limb's largest half thickness +
        (1 + 2 n_segments) delta_y, plus head and torso from R_VEL.

        Each measured segment length is off by up to 2 delta_y and the root by delta_y (the seed
        adds a single delta_y). Sound when the root's speed stays below its v_max and the limb
        lengths are rigid.
        """
        p = self.params
        sk = self.skeleton
        tau = np.asarray(t_end_s, dtype=float) + p.delay_s
        lengths = np.zeros((y.shape[0], len(sk.limb_chains)))
        for i, chain in enumerate(sk.limb_chains):
            seg = y[:, list(chain[1:])] - y[:, list(chain[:-1])]
            lengths[:, i] = np.linalg.norm(seg, axis=-1).sum(axis=-1)
        n_seg = np.array([len(c) - 1 for c in sk.limb_chains])
        r_limb = (
            p.v_max_mps[self.limb_root][None, None] * tau[None, :, None]
            + lengths[:, None]
            + self.limb_half_th
            + (1 + 2 * n_seg) * p.delta_y_m
        )  # (H, K, n_limbs)
        centre = y[:, self.limb_root]  # (H, n_limbs, 3)
        H, K = y.shape[0], tau.shape[0]
        limb_ends = np.broadcast_to(centre[:, None, :, None], (H, K, len(self.limb_root), 2, 3))
        core = self.vel(y, t_end_s)
        ends = np.concatenate([limb_ends, core.ends[:, :, self.limb_pos_parts]], axis=2)
        radius = np.concatenate([r_limb, core.radius[:, :, self.limb_pos_parts]], axis=2)
        return Occupancy("pos", ends, radius, self.pos_names)

    def iso13855(self, y: np.ndarray, t_end_s: np.ndarray) -> Occupancy:
        """ISO 13855 expansion (seed 000 Sec. III-A): every body part's capsule at the measured
        pose, radius iso_radius + delta_y + v_iso tau. Sound when no point moves faster than
        v_iso (1.6 m/s upper body, 2.0 m/s full body): real fast motion breaks this (seed 000).
        """
        p = self.params
        tau = np.asarray(t_end_s, dtype=float) + p.delay_s
        radius = p.iso_radius_m[None, :] + p.delta_y_m + p.iso_v_max_mps * tau[:, None]
        ends = np.stack([y[:, self.ja], y[:, self.jb]], axis=2)
        H, K = y.shape[0], tau.shape[0]
        return Occupancy(
            "iso13855",
            np.broadcast_to(ends[:, None], (H, K) + ends.shape[1:]),
            np.broadcast_to(radius[None], (H, K, radius.shape[1])),
            self.part_names,
        )

    def model(
        self,
        name: str,
        y: np.ndarray,
        v: np.ndarray | None,
        dv: np.ndarray | None,
        t_start_s: np.ndarray,
        t_end_s: np.ndarray,
    ) -> Occupancy:
        """One model by name, on validated inputs. ``acc`` needs ``v`` and ``dv``."""
        t_start_s, t_end_s = check_intervals(t_start_s, t_end_s)
        y = self.check_positions(y)
        if name == "vel":
            return self.vel(y, t_end_s)
        if name == "pos":
            return self.pos(y, t_end_s)
        if name == "iso13855":
            return self.iso13855(y, t_end_s)
        if name == "acc":
            v, dv = self.check_velocities(y, v, dv)
            return self.acc(y, v, dv, t_start_s, t_end_s)
        if name == "arm":
            from sara_app.human.arm import arm_occupancy

            return arm_occupancy(self, y, t_start_s, t_end_s)
        raise UnknownNameError("reachability model", name, MODELS)

    def check_velocities(
        self, y: np.ndarray, v: np.ndarray | None, dv: np.ndarray | None
    ) -> tuple[np.ndarray, np.ndarray]:
        if v is None:
            raise InputError("the acc model needs joint velocities; none were given")
        v = np.asarray(v, dtype=float).reshape(y.shape) if np.size(v) == y.size else np.asarray(v)
        if v.shape != y.shape:
            raise InputError(f"joint velocities have shape {v.shape}; expected {y.shape}")
        if not np.all(np.isfinite(v)):
            raise InputError("joint velocities are not finite")
        if dv is None:
            dv = np.full(y.shape[:2], self.params.delta_v_mps)
        dv = np.broadcast_to(np.asarray(dv, dtype=float), y.shape[:2])
        if not np.all(np.isfinite(dv)) or np.any(dv < 0):
            raise InputError("velocity error bounds must be finite and >= 0")
        return v, dv
