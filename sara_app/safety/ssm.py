"""Speed and separation monitoring: human reachable sets against the robot's occupancy, per
interval of a shielded trajectory (Schepp et al. 2022 Sec. II-B/C, Thumm et al. 2024 Sec. III-B).

An interval is safe for a human when each body part is cleared there by at least one enabled
model: the model's capsule that contains THAT part is free of every robot link capsule of the
interval (Schepp et al. 2022 ask one model's whole set to be free: a special case); the
trajectory is safe when every interval is safe for every human. This is sound exactly when each
enabled model is sound for the human's motion (its parameters bound it): with "any model
free", one unsound model makes the verdict unsound.

Hot path: one compiled call for every person (:func:`~sara_app.safety.ssm_kernels.ssm_kernel`):
per person and model, the model's capsules from the person's measurement time against every
link capsule of the intervals still to clear (bounding spheres prune, exact segment distances
decide). Models are tried in :attr:`SsmVerifier.order` (the given order at first; the shield
puts the model that completed its last successful check first) and only for intervals that no
earlier model has cleared. Pereira's arm model (numpy) is computed before the call when it is
enabled.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from sara_app.errors import InputError, UnknownNameError
from sara_app.geometry.shape_kernels import pair_distances
from sara_app.human.legs import no_bounds
from sara_app.human.reach import MODELS, HumanReach, part_capsules
from sara_app.human.reach_kernels import KINDS
from sara_app.kernel_types import as_f8
from sara_app.safety.ssm_kernels import KIND_ARM, ssm_kernel

_CODES = {**KINDS, "arm": KIND_ARM}


@dataclass
class SsmResult:
    """``safe``: every body part of every human cleared on every interval. ``free (H, M, K)``:
    model ``m``'s whole set of human ``h`` is free of the robot on interval ``k`` (False also
    where it was not evaluated because the earlier models had cleared every part there: see
    ``evaluated``). ``closest_m (H, M)``: the exact smallest surface distance between that
    model's sets and the robot capsules over the intervals it was evaluated on (negative:
    overlap; ``inf`` where not evaluated). ``parts_clear (H, K, P)``: body part ``p`` proved
    free on interval ``k`` by some model's capsule for it."""

    safe: bool
    free: np.ndarray
    evaluated: np.ndarray
    closest_m: np.ndarray
    parts_clear: np.ndarray
    models: tuple[str, ...] | None = None
    """The models along the ``M`` axis, in the order the check tried them (None: the
    verifier's own order)."""


def boxes_of(ends: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned boxes ``(lo, hi)`` ``(..., 3)`` of capsules ``(..., 2, 3)``, ``(...)``."""
    r = radius[..., None]
    return np.minimum(ends[..., 0, :], ends[..., 1, :]) - r, np.maximum(
        ends[..., 0, :], ends[..., 1, :]
    ) + r


def body_distance(
    y: np.ndarray,
    part_joints: np.ndarray,
    half_thickness_m: np.ndarray,
    robot_ends: np.ndarray,
    robot_radius: np.ndarray,
) -> float:
    """Smallest surface distance (m) between one person's body parts (joints ``y (J, 3)``,
    ``part_joints (P, 2)``, ``half_thickness_m (P,)``) and robot capsules ``(L, 2, 3)``,
    ``(L,)``; negative when they overlap."""
    P, L = len(part_joints), len(robot_radius)
    if np.shape(robot_ends) != (L, 2, 3) or np.shape(half_thickness_m) != (P,):
        raise InputError(
            f"robot capsules {np.shape(robot_ends)}, {np.shape(robot_radius)} and half "
            f"thicknesses {np.shape(half_thickness_m)}; expected (L, 2, 3), (L,) and ({P},)"
        )
    d = np.empty((1, P, L))
    parts = np.asarray(y, dtype=np.float64)[part_joints][None]  # (1, P, 2, 3)
    pair_distances(
        parts, np.asarray(half_thickness_m, dtype=np.float64)[None],
        np.asarray(robot_ends, dtype=np.float64)[None],
        np.asarray(robot_radius, dtype=np.float64)[None], d,
    )  # fmt: skip
    return float(d.min())


class SsmVerifier:
    """Checks human sets from :class:`HumanReach` against robot interval capsules.

    The models are tried in :attr:`order`, which starts as given and changes only by
    :meth:`promote` (the shield puts the model that completed its last successful check first).
    The order does not change the verdict or which body parts are proved clear (a part is clear
    when some model's capsule for it is free; a model is skipped only on intervals whose every
    part an earlier one cleared); it changes how many models a check evaluates, and so which
    ones ``free``, ``evaluated`` and ``closest_m`` report."""

    def __init__(self, reach: HumanReach, models: tuple[str, ...] | list[str]) -> None:
        bad = [m for m in models if m not in MODELS]
        if bad:
            raise UnknownNameError("reachability model", bad[0], MODELS)
        self.reach = reach
        self.models = tuple(models)
        self._model_rows = [MODELS.index(m) for m in self.models]  # rows of a widening
        self._zeros: dict[tuple[int, int, int], np.ndarray] = {}
        self._maps = np.array([part_capsules(reach, m) for m in self.models], dtype=np.int64)
        self._maps.flags.writeable = False
        self._codes = np.array([_CODES[m] for m in self.models], dtype=np.int64)
        self._constants = reach.kernel_constants()
        self._sizes = (reach.skeleton.n_parts, reach.skeleton.n_joints)  # P, J (human()'s)
        self._orders: dict[tuple[str, ...], tuple[np.ndarray, np.ndarray, list[int]]] = {}
        self.order = self.models
        """The models in the order the check tries them."""
        self.set_order(self.models)
        self._no_arm = (np.zeros((0, 1, 1, 2, 3)), np.zeros((0, 1, 1)))
        self._warm_up()

    def set_order(self, order: tuple[str, ...]) -> None:
        """Try the models in ``order`` (a permutation of :attr:`models`): the kernel's codes,
        part maps and widening rows in that order, built once per order."""
        order = tuple(order)
        if sorted(order) != sorted(self.models):
            raise InputError(f"model order {order}; expected an order of {self.models}")
        arrays = self._orders.get(order)
        if arrays is None:
            idx = [self.models.index(m) for m in order]
            codes, maps = self._codes[idx], self._maps[idx]
            codes.flags.writeable = maps.flags.writeable = False
            arrays = self._orders[order] = (codes, maps, [self._model_rows[i] for i in idx])
        self.order = order
        self._check_codes: np.ndarray = arrays[0]
        self._check_maps: np.ndarray = arrays[1]
        self._check_rows: list[int] = arrays[2]

    def promote(self, model: str) -> None:
        """Try ``model`` first from now on (the others keep their order)."""
        if model not in self.models:
            raise UnknownNameError("model of this check", model, self.models)
        if self.order[0] != model:
            self.set_order((model, *(m for m in self.order if m != model)))

    def _warm_up(self) -> None:
        """One verification and one :func:`body_distance` at construction (every model, a robot
        capsule on the person): the compiled kernels' first-call dispatch happens here, not in
        the first control cycle."""
        sk = self.reach.skeleton
        y = np.zeros((1, sk.n_joints, 3))
        ends, radius = np.zeros((2, 1, 2, 3)), np.full((2, 1), 0.1)
        self.verify(y, y, np.zeros((1, sk.n_joints)), np.zeros(1), np.array([0.0, 0.01, 0.02]),
                    ends, radius)  # fmt: skip
        half = self.reach.params.half_thickness_m
        body_distance(y[0], sk.part_joints, half, ends[0], radius[0])

    def verify(
        self,
        y: np.ndarray,
        v: np.ndarray,
        dv: np.ndarray,
        age_s: np.ndarray,
        times_s: np.ndarray,
        robot_ends: np.ndarray,
        robot_radius: np.ndarray,
        widen_m: np.ndarray | None = None,
        caps: np.ndarray | None = None,
    ) -> SsmResult:
        """The check in :attr:`order` (the result's ``M`` axis): ``y, v (H, J, 3)``, ``dv (H,
        J)``, ``age_s (H,)`` (command time minus measurement time), ``times_s (K+1,)`` from now,
        robot ``(K, L, 2, 3)``, ``(K, L)``; ``widen_m``
        ``(H, len(MODELS), P)``: extra radius per body part (:mod:`sara_app.human.widening`;
        a capsule grows by the largest of the parts it contains); ``caps (H, P, 2)``: the
        height bounds of unmeasured legs (:func:`~sara_app.human.legs.leg_caps`; None: none);
        other shapes raise :class:`InputError`."""
        times_s, robot_ends, robot_radius = as_f8(times_s), as_f8(robot_ends), as_f8(robot_radius)
        K = robot_ends.shape[0]
        L = robot_ends.shape[1] if robot_ends.ndim == 4 else -1
        human = self.human(y, v, dv, age_s, widen_m, caps)
        if (
            times_s.shape != (K + 1,)
            or robot_ends.shape != (K, L, 2, 3)
            or robot_radius.shape != (K, L)
        ):
            raise InputError(
                f"times_s {times_s.shape} and the robot {robot_ends.shape}, "
                f"{robot_radius.shape}; expected (K+1,), (K, L, 2, 3) and (K, L)"
            )
        H, M, P = human[0].shape[0], len(self.models), self.reach.skeleton.n_parts
        free = np.empty((H, M, K), dtype=bool)
        evaluated = np.empty((H, M, K), dtype=bool)
        closest = np.empty((H, M))
        parts = np.empty((H, K, P), dtype=bool)
        safe = ssm_kernel(
            human, self._constants, self._check_codes, self._check_maps,
            self._arm_sets(human[0], human[4], times_s), times_s, robot_ends, robot_radius,
            free, evaluated, closest, parts,
        )  # fmt: skip
        return SsmResult(bool(safe), free, evaluated, closest, parts, self.order)

    def human(
        self,
        y: np.ndarray,
        v: np.ndarray,
        dv: np.ndarray,
        age_s: np.ndarray,
        widen_m: np.ndarray | None = None,
        caps: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The people as the kernels take them (:data:`~sara_app.safety.ssm_kernels.HUMAN`):
        ``(y, v, dv, widen (H, M, P) in the check's model order, age_s, caps (H, P, 2))`` as
        float64; raises :class:`InputError` on shapes other than :meth:`verify`'s."""
        y, v, dv, age_s = as_f8(y), as_f8(v), as_f8(dv), as_f8(age_s)
        H, M = y.shape[0], len(self.models)
        P, J = self._sizes
        shapes = (y.shape, v.shape, dv.shape, age_s.shape)
        if shapes != ((H, J, 3), (H, J, 3), (H, J), (H,)):
            raise InputError(
                f"y, v, dv, age_s have shapes {shapes}; expected ({H}, {J}, 3) twice, "
                f"({H}, {J}) and ({H},)"
            )
        if widen_m is None:
            widen = self._zero_widening(H, M, P)
        else:
            widen = as_f8(widen_m)
            if widen.shape != (H, len(MODELS), P):
                raise InputError(
                    f"widen_m has shape {widen.shape}; expected ({H}, {len(MODELS)}, {P})"
                )
            widen = widen[:, self._check_rows]  # rows in the check's model order
        if caps is None:
            caps = no_bounds(H, P)
        else:
            caps = as_f8(caps)
            if caps.shape != (H, P, 2):
                raise InputError(f"caps has shape {caps.shape}; expected ({H}, {P}, 2)")
        return y, v, dv, widen, age_s, caps

    @property
    def part_maps(self) -> np.ndarray:
        """``(M, P)`` read-only: per model of the check, the capsule that holds each body part
        (:func:`~sara_app.human.reach.part_capsules`, computed once)."""
        return self._maps

    def _zero_widening(self, H: int, M: int, P: int) -> np.ndarray:
        """A read-only ``(H, M, P)`` of zeros, one per shape (no allocation per cycle)."""
        zeros = self._zeros.get((H, M, P))
        if zeros is None:
            zeros = self._zeros[(H, M, P)] = np.zeros((H, M, P))
            zeros.flags.writeable = False
        return zeros

    def kernel_inputs(self) -> tuple[Any, np.ndarray, np.ndarray, Any] | None:
        """``(constants, codes (M,), part maps (M, P), arm sets)`` of the check in
        :attr:`order` for a compiled caller (:mod:`~sara_app.safety.ssm_cycle_kernels`); None
        when the check uses Pereira's arm model (its capsules depend on the trajectory's times:
        computed in numpy)."""
        if "arm" in self.models:
            return None
        return self._constants, self._check_codes, self._check_maps, self._no_arm

    def _arm_sets(
        self, y: np.ndarray, age_s: np.ndarray, times_s: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Pereira's arm model's capsules per person ``(H, Ke, C, 2, 3)``, ``(H, K, C)`` (numpy,
        :func:`~sara_app.human.arm.arm_occupancy`); empty when the check does not use it."""
        if "arm" not in self.models:
            return self._no_arm
        from sara_app.human.arm import arm_occupancy

        occ = [
            arm_occupancy(self.reach, y[h : h + 1], times_s[:-1] + a, times_s[1:] + a)
            for h, a in enumerate(age_s.tolist())
        ]
        return np.concatenate([o.ends for o in occ]), np.concatenate([o.radius for o in occ])
