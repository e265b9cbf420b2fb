"""One person's PFL check with all of its models in one compiled call: the shield's common case.

:class:`~sara_app.safety.pfl_shield.PflShield` checks a trajectory model by model (see its
notes): per model the person's capsules over the intervals still unproved, the compiled
classification (the link states obtained on the first possible contact) and the per-entry
merge. Composed in Python that is ~40 calls per check, and in the benchmark's braking cycle
(two checks, four model evaluations) their glue cost more than the arithmetic (~250 of ~800 us).
:class:`FusedCheck` runs the same composition as one kernel
(:func:`~sara_app.safety.pfl_fused_kernel.fused_kernel`) on the same numbers, so the verdicts,
classes, thresholds, margins and link energies are the same bits as the Python path, which stays
the reference and serves what this does not: several people at once, the arm model, a robot
without the compiled CRBA (``tests/test_pfl_fused.py`` compares them cycle by cycle on
closed-loop episodes of a person walking into reach and out with noisy velocities and ages, on
the benchmark's states and on non-finite person inputs).

Buffers: the results' arrays are fresh per check (a :class:`PflResult` may be kept); the
robot-only geometry, the human sets and the later models' classifications use scratch buffers
per trajectory length, so only the most recently opened check may add models.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sara_app.errors import InputError, ParameterError
from sara_app.human.reach import MODELS, HumanReach
from sara_app.safety.contact import ContactResult
from sara_app.safety.pfl import PflCheck, PflResult
from sara_app.safety.pfl_fused_kernel import (
    KIND_ACC,
    KIND_ISO,
    KIND_POS,
    KIND_VEL,
    check_buffers,
    check_results,
    fused_kernel,
)
from sara_app.safety.pfl_link_states import PathLinkStates
from sara_app.safety.shield import Humans

__all__ = ["KINDS", "FusedCheck", "FusedChecks", "result_of"]

KINDS = {"acc": KIND_ACC, "vel": KIND_VEL, "iso13855": KIND_ISO, "pos": KIND_POS}
"""The models the kernel computes (the arm model is left to the Python path)."""


class FusedChecks:
    """Opens :class:`FusedCheck` s for one robot, one kind of person and one shield's models.

    ``pfl``: the check for one person (its thresholds, classifier and robot); ``link_states``:
    the link states of the same robot (their compiled kernel is required: see
    :attr:`PathLinkStates.compiled`); ``reach``: the person's models; ``part_maps``: per model
    name the capsule of each body part (``(P,)``; see
    :func:`~sara_app.human.reach.part_capsules`); ``boxes``: the environment
    ``T_world_box (B, 4, 4)``, ``half_extents_m (B, 3)`` (validated by the caller).
    """

    def __init__(
        self,
        pfl: PflCheck,
        link_states: PathLinkStates,
        reach: HumanReach,
        part_maps: dict[str, np.ndarray],
        boxes: tuple[np.ndarray, np.ndarray],
    ) -> None:
        unknown = sorted(set(part_maps) - set(KINDS))
        if unknown or not link_states.compiled:
            raise ParameterError(
                f"models {unknown} / compiled link states {link_states.compiled}: the fused "
                f"check needs models among {sorted(KINDS)} and the compiled CRBA"
            )
        self.pfl, self.link_states, self.reach = pfl, link_states, reach
        P, L, J = pfl.n_parts, pfl.n_links, reach.skeleton.n_joints
        if reach.skeleton.n_parts != P:
            raise ParameterError(
                f"the check has {P} body parts, the reach model {reach.skeleton.n_parts}; "
                "expected one person's parts"
            )
        maps = np.tile(np.arange(P, dtype=np.int64), (len(KINDS), 1))
        n_pos = int(reach.pos_ends.shape[0])
        for name, index in part_maps.items():
            n = n_pos if name == "pos" else P  # capsules of the model (the kernel indexes them)
            idx = np.asarray(index)
            if idx.shape != (P,) or not (np.all(idx >= 0) and np.all(idx < n)):
                raise ParameterError(
                    f"part map of {name!r}: {idx.tolist()}; expected {P} capsule indices in "
                    f"[0, {n})"
                )
            maps[KINDS[name]] = idx
        self._J, self._P, self._L, self._n = J, P, L, pfl.model.n_dof
        # the widening's rows (reach.MODELS order) in the kernel's model-kind order
        self._kind_rows = np.array(
            [MODELS.index(m) for m in sorted(KINDS, key=KINDS.__getitem__)], dtype=np.int64
        )
        r, p = reach, reach.params
        self._static = (r.part_joints, np.stack([r.vel_base, r.iso_base]),
                        np.stack([r.vel_speed, r.iso_speed]))  # fmt: skip
        self._acc = (r.a_half, np.asarray(p.half_thickness_m, float), r.acc_ia, r.acc_ib,
                     r.acc_ends)  # fmt: skip
        self._pos = (r.pos_seg_a, r.pos_seg_b, r.pos_seg_limb, r.pos_ends, r.pos_rspeed,
                     r.pos_rbase)  # fmt: skip
        self._n_pos = n_pos
        rules = (*pfl.classifier.kernel_arrays(), pfl.T_clamp, pfl.T_free)
        self._models = (
            rules, pfl.classifier.switches(), self._static, self._acc, self._pos,
            (float(p.delay_s), float(p.delta_y_m)), int(r.n_limbs), maps,
        )  # fmt: skip
        self._link_constants = link_states.kernel_constants()
        self._s_radius = np.asarray(pfl.model.radius_m, dtype=np.float64)
        self._boxes = boxes
        self._scratch: dict[int, tuple[Any, ...]] = {}
        self._orders: dict[tuple[str, ...], np.ndarray] = {}
        self.no_energy = np.zeros(L)
        self.opened = 0
        """Checks opened so far (the scratch buffers belong to the latest)."""

    def codes(self, order: list[str]) -> np.ndarray:
        """The kernel's codes of a model order (cached per order)."""
        key = tuple(order)
        c = self._orders.get(key)
        if c is None:
            c = self._orders[key] = np.array([KINDS[m] for m in order], dtype=np.int64)
        return c

    def _scratch_for(self, K: int) -> tuple[Any, ...]:
        """``(geometry, link buffers, sets, scratch classification)`` for checks of ``K``
        intervals (:func:`~sara_app.safety.pfl_fused_kernel.check_buffers`, once per ``K``)."""
        s = self._scratch.get(K)
        if s is None:
            L, P, B, C, n = self._L, self._P, self._boxes[0].shape[0], self._n_pos, self._n
            T0 = self.link_states.base_pose()
            s = self._scratch[K] = check_buffers(K, L, P, B, C, n, T0)
        return s

    def kernel_constants(self) -> tuple[Any, ...]:
        """The check's per-shield constants as the kernels take them
        (:data:`~sara_app.safety.pfl_fused_kernel.MODELS`)."""
        return self._models

    def validated(
        self,
        traj: Any,
        r_ends: np.ndarray,
        r_radius: np.ndarray,
        hum: Humans,
    ) -> tuple[
        tuple[np.ndarray, ...],
        tuple[np.ndarray, ...],
        tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        float,
    ]:
        """``(robot, trajectory, human, age)`` as the kernel takes them: the shielded trajectory
        ``traj`` with its robot capsules per interval ``r_ends (K, L, 2, 3)``, ``r_radius (K,
        L)`` and one person ``hum = (y, v (1, J, 3), dv (1, J), age (1,), widen (1, M, P))``
        (the widening's rows go to the kernel in its model-kind order), as float64;
        raises :class:`InputError` on other shapes."""
        trajectory = self.link_states.inputs(traj)
        K = trajectory[0].shape[0] - 1
        L, J = self._L, self._J
        r_ends = np.asarray(r_ends, dtype=np.float64)
        r_radius = np.asarray(r_radius, dtype=np.float64)
        y, v, dv, age, widen = (np.asarray(a, dtype=np.float64) for a in hum)
        P = self._P
        if (
            r_ends.shape != (K, L, 2, 3) or r_radius.shape != (K, L) or y.shape != (1, J, 3)
            or v.shape != (1, J, 3) or dv.shape != (1, J) or age.shape != (1,)
            or widen.shape != (1, len(MODELS), P)
        ):  # fmt: skip
            raise InputError(
                f"fused PFL check inputs r_ends {r_ends.shape}, r_radius {r_radius.shape}, y "
                f"{y.shape}, v {v.shape}, dv {dv.shape}, age {age.shape}, widen {widen.shape}; "
                f"expected ({K}, {L}, 2, 3), ({K}, {L}), (1, {J}, 3), (1, {J}, 3), (1, {J}), "
                f"(1,), (1, {len(MODELS)}, P) for one person"
            )
        robot = (r_ends, r_radius, *self._boxes, self._s_radius)
        widen_kinds = np.ascontiguousarray(widen[0][self._kind_rows])  # rows in KIND order
        return robot, trajectory, (y, v, dv, widen_kinds), float(age[0])

    def open(
        self,
        traj: Any,
        r_ends: np.ndarray,
        r_radius: np.ndarray,
        hum: Humans,
    ) -> FusedCheck:
        """A check of the shielded trajectory ``traj`` against one person (inputs as in
        :meth:`validated`)."""
        robot, trajectory, human, age = self.validated(traj, r_ends, r_radius, hum)
        self.opened += 1
        return FusedCheck(self, trajectory, robot, human, age)


class FusedCheck:
    """One open check (see :class:`FusedChecks`); :attr:`models`, :attr:`todo`,
    :meth:`add_models`, :meth:`result` and :attr:`E0` as the shield uses a
    :class:`~sara_app.safety.pfl.MergedCheck`."""

    def __init__(
        self,
        owner: FusedChecks,
        trajectory: tuple[np.ndarray, ...],
        robot: tuple[np.ndarray, ...],
        human: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
        age: float,
    ) -> None:
        self._owner, self._ticket = owner, owner.opened
        K, L, P = robot[1].shape[0], owner._L, owner._P
        self.K = K
        geometry, self._link_buffers, self._sets, self._scratch = owner._scratch_for(K)
        geometry[4].fill(-2)
        geometry[5].fill(-2)
        self._geometry = geometry
        self._trajectory, self._human, self._age = trajectory, human, age
        self._robot = robot
        self._slabs, self._first, self._verdict, self._state = check_results(K, L, P)

    @property
    def models(self) -> int:
        """Models evaluated so far."""
        return int(self._state[0])

    @property
    def todo(self) -> tuple[int, int]:
        """Interval range ``lo:hi`` with unproved entries (``(K, K)``: every entry proved)."""
        return int(self._state[1]), int(self._state[2])

    @property
    def energy_known(self) -> bool:
        """Whether the link states were obtained (some human set may touch a link)."""
        return bool(self._state[3])

    def add_models(
        self,
        order: np.ndarray,
        stop: int,
        first_only: bool,
        replan: tuple[float, float] | None = None,
        cut: float = 1.0,
    ) -> int:
        """Add the models ``order[models:stop]`` (codes from :meth:`FusedChecks.codes`) until
        every entry is proved or, with ``first_only``, after one, or with ``replan = (cap,
        c_min)`` after a failing first model that a replan will follow (fixable, and the
        replan's cap ``min(cut * candidate, cut * min(cap, max s'))`` at least ``c_min``: the
        shield's ``_next_cap``); returns the index in ``order`` of the model that completed the
        check (-1: none)."""
        o = self._owner
        if self._ticket != o.opened:
            raise InputError("a later PFL check reuses this one's buffers; it cannot add models")
        if not (0 <= stop <= order.shape[0]):
            raise InputError(f"stop = {stop}; expected 0 <= stop <= {order.shape[0]} models")
        done = fused_kernel(
            self._robot, self._geometry, self._trajectory, o._link_constants,
            self._link_buffers, o._models, self._human, self._age, self._sets, order, stop,
            first_only, (replan is not None, *(replan or (0.0, 0.0)), cut), self._first,
            self._scratch, self._verdict, self._state,
        )  # fmt: skip
        if done == -2:
            raise InputError("a fused PFL check has unproved entries but no link energies")
        return int(done)

    @property
    def safe_all(self) -> bool:
        """Eq. 6 for the models added so far."""
        return bool(self._state[5])

    def candidate(self) -> tuple[float, bool]:
        """After a failed check: the candidate path speed of the violated entries and whether a
        slower plan can fix them (as :func:`~sara_app.safety.pfl_scaling.candidate` from
        :meth:`result`)."""
        return float(self._verdict[9][0]), not self._state[6]

    def allowed_speed(self) -> float:
        """After a verified check: the path speed at which its contacts reach their thresholds
        (as :func:`~sara_app.safety.pfl_scaling.allowed_speed` from :meth:`result`)."""
        return float(self._verdict[9][1])

    @property
    def E0(self) -> np.ndarray:
        """Link energies at the current state ``(L,)`` (a view, valid until the next check of a
        trajectory as long; zeros when no contact was possible, then unused)."""
        if self._state[3]:
            return self._link_buffers[9][0]
        return self._owner.no_energy

    def result(self) -> PflResult:
        """The merged verdict, as :meth:`MergedCheck.result <sara_app.safety.pfl.MergedCheck>`;
        raises :class:`InputError` before any model was added."""
        if self._state[0] == 0:
            raise InputError("no human set was checked (add at least one model)")
        return result_of(self._slabs, self._state)


def result_of(slabs: tuple[np.ndarray, ...], state: np.ndarray) -> PflResult:
    """The :class:`PflResult` of a check's result arrays and state (the layout of
    :func:`~sara_app.safety.pfl_fused_kernel.check_results`), as
    :meth:`MergedCheck.result <sara_app.safety.pfl.MergedCheck>` builds it."""
    b5, f3, i2, stack, diam, safe_k, f2, part = slabs
    contact, contact_s, env, self_, safe = b5
    thr, margin, d_rh = f3
    cls, cls_m = i2
    allowed, E_int = f2
    c = ContactResult(contact, contact_s, env, self_, cls, stack, diam, d_rh)
    merged = bool(state[4])
    return PflResult(
        safe, safe_k, bool(state[5]), cls_m if merged else cls, thr, E_int, margin, c, allowed,
        part, merged or bool(state[3]),
    )  # fmt: skip
