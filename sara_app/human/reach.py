"""Human reachable occupancy as capsules: SaRA's R_POS, R_VEL, R_ACC (Schepp et al. 2022 Sec. II-B)
and the ISO 13855 expansion model (Pereira & Althoff 2016 Sec. III-A); Pereira's arm model lives in
``arm.py``.

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

import math
from typing import Any

import numpy as np

from sara_app.errors import InputError, ParameterError, UnknownNameError
from sara_app.human.arm import arm_occupancy
from sara_app.human.model_names import MODELS, MOVING_MODELS
from sara_app.human.occupancy import Occupancy
from sara_app.human.params import ReachParams
from sara_app.human.reach_kernels import (
    KINDS,
    acc_sets,
    combined_sets,
    people_sets,
    pos_sets,
    static_sets,
)
from sara_app.human.skeleton import skeleton
from sara_app.kernel_types import FLOAT64, as_f8, entry

# The model methods check their inputs' dtypes and shapes, then call the compiled code directly
# (kernel_types.entry: no per-call dispatch; a one-person set costs mostly such Python glue:
# Schepp et al.'s C++ computes all three sets in 3 us).
_STATIC_SETS, _ACC_SETS, _COMBINED_SETS, _POS_SETS, _PEOPLE_SETS = (
    entry(k) for k in (static_sets, acc_sets, combined_sets, pos_sets, people_sets)
)


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
        # R_POS: one ball per limb, then head and torso from R_VEL (the paper's four balls leave
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
        self._tables()
        # (model, H, K) -> the Occupancy a buffered model method returns and its two buffers
        self._outputs: dict[tuple[str, int, int], tuple[Occupancy, np.ndarray, np.ndarray]] = {}
        # people_sets' one-interval buffers and the kernels' constants, built at first use
        self._people_buffers: tuple[tuple[np.ndarray, ...], tuple[Any, ...]] | None = None
        self._n_joints = sk.n_joints

    def _tables(self) -> None:
        """Per-capsule coefficients and int64 index tables of the compiled model kernels
        (:mod:`sara_app.human.reach_kernels`)."""
        sk, p = self.skeleton, self.params
        J = sk.n_joints
        ja, jb, ball = self.ja, self.jb, self.is_ball
        i64 = np.int64
        self.part_joints = np.ascontiguousarray(sk.part_joints, dtype=i64)
        # R_VEL / ISO: radius = base + speed * tau (max over the two joints, radius monotone).
        self.vel_base = p.delta_y_m + p.half_thickness_m
        self.vel_speed = np.maximum(p.v_max_mps[ja], p.v_max_mps[jb])
        # R_VEL's displacement bound per part (P, N): the larger of its two joints' (inf: ISO).
        disp = np.asarray(p.disp_max_m, dtype=np.float64)
        self.vel_disp = np.maximum(disp[ja], disp[jb])
        self.disp_step_s = float(p.disp_step_s)
        self.no_disp = np.zeros((sk.n_parts, 0))
        self.iso_base = p.delta_y_m + p.iso_radius_m
        self.iso_speed = np.full(sk.n_parts, p.iso_v_max_mps)
        # R_ACC: per joint X = [R(tau_b) | R(tau_b) + |v| (tau_b - tau_a) / 2]; ball parts take
        # the first, two-joint parts the second (see ``acc``). Centres C = [tau_a | mid | tau_b].
        self.acc_ia = np.where(ball, ja, J + ja).astype(i64)
        self.acc_ib = np.where(ball, jb, J + jb).astype(i64)
        self.acc_ends = np.stack(
            [np.where(ball, ja, J + ja), np.where(ball, 2 * J + jb, J + jb)], 1
        ).astype(i64)
        self.a_half = 0.5 * p.a_max_mps2
        self.a_max = np.asarray(p.a_max_mps2, dtype=np.float64)
        self.v_max = np.asarray(p.v_max_mps, dtype=np.float64)
        # R_POS: all limb segments; segment i belongs to limb pos_seg_limb[i].
        seg = [(a, b, i) for i, c in enumerate(sk.limb_chains) for a, b in zip(c[:-1], c[1:])]
        self.pos_seg_a = np.array([a for a, _, _ in seg], dtype=i64)
        self.pos_seg_b = np.array([b for _, b, _ in seg], dtype=i64)
        self.pos_seg_limb = np.array([i for _, _, i in seg], dtype=i64)
        n_seg = np.array([len(c) - 1 for c in sk.limb_chains])
        self.pos_base = self.limb_half_th + (1 + 2 * n_seg) * p.delta_y_m
        self.pos_speed = p.v_max_mps[self.limb_root]
        self.pos_ends = np.concatenate(
            [np.repeat(self.limb_root[:, None], 2, 1), sk.part_joints[self.limb_pos_parts]]
        ).astype(i64)
        self.pos_rbase = np.concatenate([self.pos_base, self.vel_base[self.limb_pos_parts]])
        self.pos_rspeed = np.concatenate([self.pos_speed, self.vel_speed[self.limb_pos_parts]])
        self.n_limbs = len(sk.limb_chains)
        self.half_th = p.half_thickness_m
        # The kernels are called without dispatch (kernel_types.entry): their constants must be
        # exactly the signatures' dtypes, whatever types the parameters came in.
        for name in ("vel_base", "vel_speed", "iso_base", "iso_speed", "a_half", "a_max",
                     "v_max", "pos_rspeed", "pos_rbase", "half_th", "vel_disp",
                     "no_disp"):  # fmt: skip
            setattr(self, name, np.ascontiguousarray(getattr(self, name), dtype=np.float64))
        # Each model's constants in its kernel's argument order, one tuple per call rather than
        # ten attribute reads (a one-person set costs mostly such per-call glue).
        delay_s, delta_y_m = float(p.delay_s), float(p.delta_y_m)
        # static_sets: radius = base + min(speed tau, disp(tau)), tau = t_end + delay (the
        # displacement bound disp (P, N); N = 0: none)
        self._vel_args = (delay_s, self.vel_base, self.vel_speed, self.vel_disp, self.disp_step_s)
        self._iso_args = (delay_s, self.iso_base, self.iso_speed, self.no_disp, self.disp_step_s)
        acc_tables = (self.half_th, self.acc_ia, self.acc_ib, self.acc_ends)
        self._acc_args = (delay_s, self.a_half, delta_y_m, *acc_tables)
        self._combined_args = (delay_s, self.a_max, self.v_max, delta_y_m, *acc_tables)
        self._pos_tables = (self.pos_seg_a, self.pos_seg_b, self.pos_seg_limb, self.pos_ends)
        self._pos_args = (delay_s, self.pos_rspeed, self.pos_rbase, self.n_limbs)

    def _output(self, name: str, H: int, K: int) -> tuple[Occupancy, np.ndarray, np.ndarray]:
        """``(occupancy, ends, radius)``: model ``name``'s buffers for ``H`` people and ``K``
        intervals, allocated once per shape (the hot path allocates nothing), and the
        Occupancy of views into them that the model method returns (the same object every call:
        its arrays are rewritten in place)."""
        key = (name, H, K)
        out = self._outputs.get(key)
        if out is None:
            out = self._outputs[key] = self._new_output(name, H, K)
        return out

    def _new_output(self, name: str, H: int, K: int) -> tuple[Occupancy, np.ndarray, np.ndarray]:
        P = self.skeleton.n_parts
        if name in ("vel", "iso13855"):  # ends at the measured pose, radius the same per human
            ends, radius = np.empty((H, P, 2, 3)), np.empty((K, P))
            return Occupancy(name, ends[:, None], radius[None], self.part_names), ends, radius
        if name == "pos":  # limb balls at the root joints
            C = self.pos_ends.shape[0]
            ends, radius = np.empty((H, C, 2, 3)), np.empty((H, K, C))
            return Occupancy(name, ends[:, None], radius, self.pos_names), ends, radius
        ends, radius = np.empty((H, K, P, 2, 3)), np.empty((H, K, P))  # acc, combined
        return Occupancy(name, ends, radius, self.part_names), ends, radius

    def _prepare(
        self, name: str, y: np.ndarray, t_end_s: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, tuple[Occupancy, np.ndarray, np.ndarray]]:
        """``y (H, J, 3)`` and ``t_end_s (K,)`` as float64 and model ``name``'s output for their
        shapes (:meth:`_output`); a shape the compiled kernels cannot index raises
        :class:`InputError` (values are the callers' to check, see ``model``). One method for
        both: a one-person set costs mostly such per-call glue."""
        # one test for both (as_f8's, per array, costs a tenth of a one-person vel set)
        if not (type(y) is type(t_end_s) is np.ndarray and y.dtype is t_end_s.dtype is FLOAT64):
            y, t_end_s = as_f8(y), as_f8(t_end_s)
        ys = y.shape
        if len(ys) != 3 or ys[1] != self._n_joints or ys[2] != 3 or t_end_s.ndim != 1:
            raise InputError(
                f"joint positions {ys} and interval ends {t_end_s.shape}; expected (H, "
                f"{self._n_joints}, 3) and (K,)"
            )
        out = self._outputs.get((name, ys[0], t_end_s.shape[0]))
        return y, t_end_s, out if out is not None else self._output(name, ys[0], t_end_s.shape[0])

    def _coverage(self, model: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Which joints each capsule of ``model`` must contain, and with which margin.

        Returns ``(capsule, joint, margin_m)`` index arrays: joint ``joint[i]``, grown by the
        body part's half thickness ``margin_m[i]``, must lie in capsule ``capsule[i]``. Every
        joint appears at least once. Used by the containment measurements and tests.
        """
        sk, p = self.skeleton, self.params
        half = p.iso_radius_m if model in ("iso13855",) else p.half_thickness_m
        rows: list[tuple[int, int, float]] = []
        if model in ("vel", "acc", "iso13855", "combined"):
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

    def _prepare_moving(
        self, name: str, y: np.ndarray, v: np.ndarray, dv: np.ndarray, t_start_s: np.ndarray,
        t_end_s: np.ndarray,
    ) -> tuple[Any, ...]:  # fmt: skip
        """As :meth:`_prepare` for the velocity-based models: ``(y, v, dv, t_start_s, t_end_s,
        output)``."""
        y, t_end_s, out = self._prepare(name, y, t_end_s)
        if not (
            type(v) is type(dv) is type(t_start_s) is np.ndarray
            and v.dtype is dv.dtype is t_start_s.dtype is FLOAT64
        ):
            v, dv, t_start_s = as_f8(v), as_f8(dv), as_f8(t_start_s)
        ys, ds = y.shape, dv.shape
        if (
            v.shape != ys
            or len(ds) != 2
            or ds[0] != ys[0]
            or ds[1] != ys[1]
            or (t_start_s.shape != t_end_s.shape)
        ):
            raise InputError(
                f"v {v.shape}, dv {dv.shape}, t_start_s {t_start_s.shape}; expected {y.shape}, "
                f"{y.shape[:2]} and {t_end_s.shape}"
            )
        return y, v, dv, t_start_s, t_end_s, out

    def kernel_constants(self) -> tuple[Any, ...]:
        """The models' constants as the compiled checks take them: ``(static, acc, pos,
        (delay_s, delta_y_m), n_limbs)`` (:func:`~sara_app.human.reach_kernels.person_sets`)."""
        p = self.params
        disp = np.stack([self.vel_disp, np.full_like(self.vel_disp, np.inf)])  # ISO: none
        static = (self.part_joints, np.stack([self.vel_base, self.iso_base]),
                  np.stack([self.vel_speed, self.iso_speed]), disp, self.disp_step_s)  # fmt: skip
        acc = (self.a_half, self.half_th, self.acc_ia, self.acc_ib,
               self.acc_ends, self.a_max, self.v_max)  # fmt: skip
        pos = (self.pos_seg_a, self.pos_seg_b, self.pos_seg_limb, self.pos_ends,
               self.pos_rspeed, self.pos_rbase)  # fmt: skip
        return static, acc, pos, (float(p.delay_s), float(p.delta_y_m)), int(self.n_limbs)

    # --- models --------------------------------------------------------------------------------

    # Outputs of vel / acc / pos / iso13855 are views into per-instance buffers, valid until the
    # next call of the same model with the same shapes; ``model`` returns copies.

    def vel(self, y: np.ndarray, t_end_s: np.ndarray) -> Occupancy:
        """R_VEL = y(0) + B(delta_y) + B(v_max tau) per joint, capsules per body part (Schepp et
        al. 2022 Sec. II-B); where the set carries a displacement bound D(tau)
        (:class:`~sara_app.human.params.DisplacementBound`), B(min(v_max tau, D(tau))).

        Sound when every joint's speed stays below its v_max and its displacement over any tau
        within D(tau) (the conformance monitor checks both).
        """
        y, t_end_s, (occ, ends, radius) = self._prepare("vel", y, t_end_s)
        _STATIC_SETS(y, self.part_joints, t_end_s, *self._vel_args, ends, radius)
        return occ

    def iso13855(self, y: np.ndarray, t_end_s: np.ndarray) -> Occupancy:
        """ISO 13855 expansion (Pereira & Althoff 2016 Sec. III-A): every body part's capsule at the
        measured pose, radius iso_radius + delta_y + v_iso tau. Sound when no point moves faster
        than v_iso (1.6 m/s upper body, 2.0 m/s full body): real fast motion breaks this (Pereira &
        Althoff 2016).
        """
        y, t_end_s, (occ, ends, radius) = self._prepare("iso13855", y, t_end_s)
        _STATIC_SETS(y, self.part_joints, t_end_s, *self._iso_args, ends, radius)
        return occ

    def acc(
        self,
        y: np.ndarray,
        v: np.ndarray,
        dv: np.ndarray,
        t_start_s: np.ndarray,
        t_end_s: np.ndarray,
    ) -> Occupancy:
        """R_ACC = y(0) + B(delta_y) + v(0) tau + B(dv tau) + B(a_max tau^2 / 2) per joint.

        Over [tau_a, tau_b] a joint's ball moves linearly and grows convexly, so the union lies
        in the capsule of its end balls with the radius at tau_b: ball body parts (head, hands,
        feet) use that capsule. A two-joint part at time tau is the hull of its joints' balls;
        over the interval it lies in the capsule between the joints' mid-interval centres with
        radius max_j (R_j(tau_b) + |v_j| (tau_b - tau_a) / 2) (a point of the hull is a convex
        combination of points of the two balls). Sound when every joint's acceleration stays
        below a_max and ``dv`` bounds the velocity error.
        """
        y, v, dv, t_start_s, t_end_s, (occ, ends, radius) = self._prepare_moving(
            "acc", y, v, dv, t_start_s, t_end_s
        )
        _ACC_SETS(y, v, dv, t_start_s, t_end_s, *self._acc_args, ends, radius)
        return occ

    def combined(
        self,
        y: np.ndarray,
        v: np.ndarray,
        dv: np.ndarray,
        t_start_s: np.ndarray,
        t_end_s: np.ndarray,
    ) -> Occupancy:
        """The combined speed-and-acceleration model: per joint the reachable ball under BOTH
        its acceleration bound from the measured velocity (R_ACC's assumption) and its speed
        bound (R_VEL's), plus ``delta_y`` (:func:`~sara_app.human.reach_kernels.combined_ball`),
        in R_ACC's capsule layout (:func:`~sara_app.human.reach_kernels.combined_sets`; per
        joint the smallest of that ball, R_ACC's and R_VEL's); a joint without a velocity
        estimate (``dv`` infinite) gets R_VEL's ball, and a part that mixes such a joint with
        one that has an estimate is unbounded (no claim: the vel model claims R_VEL's
        capsule). Sound when every joint's acceleration stays below a_max and its speed below
        v_max, and ``dv`` bounds the velocity error."""
        y, v, dv, t_start_s, t_end_s, (occ, ends, radius) = self._prepare_moving(
            "combined", y, v, dv, t_start_s, t_end_s
        )
        _COMBINED_SETS(y, v, dv, t_start_s, t_end_s, *self._combined_args, ends, radius)
        return occ

    def pos(self, y: np.ndarray, t_end_s: np.ndarray) -> Occupancy:
        """R_POS: per limb a ball at its root joint (shoulder or hip) of radius
        v_root tau + sum of the measured segment lengths + the limb's largest half thickness +
        (1 + 2 n_segments) delta_y, plus head and torso from R_VEL.

        Each measured segment length is off by up to 2 delta_y and the root by delta_y (the paper
        adds a single delta_y). Sound when the root's speed stays below its v_max and the limb
        lengths are rigid.
        """
        y, t_end_s, (occ, ends, radius) = self._prepare("pos", y, t_end_s)
        _POS_SETS(y, *self._pos_tables, t_end_s, *self._pos_args, ends, radius)
        return occ

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
            o = self.vel(y, t_end_s)
        elif name == "pos":
            o = self.pos(y, t_end_s)
        elif name == "iso13855":
            o = self.iso13855(y, t_end_s)
        elif name == "acc":
            v, dv = self.check_velocities(y, v, dv)
            o = self.acc(y, v, dv, t_start_s, t_end_s)
        elif name == "combined":
            v, dv = self.check_velocities(y, v, dv)
            o = self.combined(y, v, dv, t_start_s, t_end_s)
        elif name == "arm":
            o = arm_occupancy(self, y, t_start_s, t_end_s)
        else:
            raise UnknownNameError("reachability model", name, MODELS)
        H, K, C = y.shape[0], t_end_s.shape[0], len(o.names)
        return Occupancy(
            o.model,
            np.array(np.broadcast_to(o.ends, (H, K, C, 2, 3))),
            np.array(np.broadcast_to(o.radius, (H, K, C))),
            o.names,
        )

    def people_sets(
        self,
        name: str,
        y: np.ndarray,
        v: np.ndarray,
        dv: np.ndarray,
        age_s: np.ndarray,
        horizon_s: float,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Model ``name`` for each person on one interval from their own measurement: person
        ``h`` (``y, v (H, J, 3)``, ``dv (H, J)``; velocities read by :data:`MOVING_MODELS`
        only) on ``[age_s[h], age_s[h] + horizon_s]``.
        Returns fresh ``ends (H, C, 2, 3)``, ``radius (H, C)``: what :meth:`model` gives person
        by person, in one compiled call (:func:`~sara_app.human.reach_kernels.people_sets`) for
        the compiled models; Pereira's arm model (numpy) person by person."""
        moving = name in MOVING_MODELS
        y, v, dv, age_s = self._people_inputs(y, v, dv, age_s, horizon_s, moving)
        if not moving:  # not read: a person's velocities need not be known yet
            v, dv = np.zeros_like(y), np.zeros(y.shape[:2])
        kind = KINDS.get(name)
        if kind is None:  # the arm model, or an unknown name (model's error)
            t_start, t_end = age_s, age_s + float(horizon_s)
            per_person = [self.model(name, y[h : h + 1], v[h : h + 1], dv[h : h + 1],
                                     t_start[h : h + 1], t_end[h : h + 1])
                          for h in range(y.shape[0])]  # fmt: skip
            return (np.stack([o.ends[0, 0] for o in per_person]),
                    np.stack([o.radius[0, 0] for o in per_person]))  # fmt: skip
        H, P = y.shape[0], self.skeleton.n_parts
        C_pos = len(self.pos_rbase)
        C = C_pos if name == "pos" else P
        if self._people_buffers is None:  # one interval's: the same for every call
            buffers: tuple[np.ndarray, ...] = (
                np.empty(1), np.empty(1), np.empty((1, 1, P, 2, 3)), np.empty((1, 1, P)),
                np.empty((1, P, 2, 3)), np.empty((1, P)), np.empty((1, C_pos, 2, 3)),
                np.empty((1, 1, C_pos)),
            )  # fmt: skip
            self._people_buffers = (buffers, self.kernel_constants())
        buffers, constants = self._people_buffers
        ends, radius = np.empty((H, C, 2, 3)), np.empty((H, C))
        # checked above: float64 arrays of the signature's dimensions (entry's contract)
        _PEOPLE_SETS(kind, y, as_f8(v), as_f8(dv), age_s, np.array([0.0, float(horizon_s)]),
                     constants, buffers, ends, radius)  # fmt: skip
        return ends, radius

    def _people_inputs(
        self, y: Any, v: Any, dv: Any, age_s: Any, horizon_s: float, moving: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`people_sets`' inputs as float64 arrays, checked in a few whole-array tests
        (the display calls it for every model: each check on its own cost more than the
        kernel); otherwise the detailed checks raise :class:`InputError` with what is wrong
        (or shape what :meth:`model` takes too). ``moving``: the velocities and their bounds
        are checked too."""
        y, v, dv, age_s = as_f8(y), as_f8(v), as_f8(dv), np.atleast_1d(as_f8(age_s))
        H, J = (y.shape[0], self._n_joints) if y.ndim == 3 else (-1, self._n_joints)
        ok = (y.shape == (H, J, 3) and age_s.shape == (H,) and bool(np.isfinite(y).all())
              and bool(np.isfinite(age_s).all()) and age_s.min(initial=0.0) >= 0.0
              and math.isfinite(horizon_s) and horizon_s >= 0.0)  # fmt: skip
        if ok and moving:
            ok = (v.shape == y.shape and dv.shape == (H, J) and bool(np.isfinite(v).all())
                  and bool(np.isfinite(dv).all()) and dv.min(initial=0.0) >= 0.0)  # fmt: skip
        if not ok:  # what is wrong, or inputs model() takes too (flat or broadcast velocities)
            y = self.check_positions(y)
            if moving:
                v, dv = self.check_velocities(y, v, dv)
                v, dv = as_f8(np.ascontiguousarray(v)), as_f8(np.ascontiguousarray(dv))
            check_intervals(age_s, age_s + float(horizon_s))
            if age_s.shape != (y.shape[0],):
                raise InputError(f"age_s has shape {age_s.shape}; expected ({y.shape[0]},)")
        return y, v, dv, age_s

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


def part_capsules(reach: HumanReach, model: str) -> np.ndarray:
    """``(P,)``: for each body part, the index of a capsule of ``model`` that contains it (both
    joints grown by the part's half thickness, from ``reach.coverage``). Raises
    :class:`ParameterError` when a body part has none."""
    cap, joint, margin = reach.coverage[model]
    sk, half = reach.skeleton, reach.params.half_thickness_m
    out = np.empty(sk.n_parts, dtype=int)
    for p, (a, b) in enumerate(sk.part_joints):
        ok_a = set(cap[(joint == a) & (margin >= half[p] - 1e-12)].tolist())
        ok_b = set(cap[(joint == b) & (margin >= half[p] - 1e-12)].tolist())
        both = sorted(ok_a & ok_b)
        if not both:
            raise ParameterError(
                f"model {model!r} has no capsule containing body part {sk.parts[p]!r}; "
                "it cannot be used for the PFL check"
            )
        out[p] = both[0]
    return out
