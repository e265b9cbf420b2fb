"""The compiled SSM check of one shielded trajectory against every person (Schepp et al. 2022's
"safe if one model proves it", per person and interval): for each person, the models in order
over the intervals no model has cleared yet, each model's capsules (:func:`person_sets`, from
that person's measurement time) against the robot's capsules per interval
(:func:`~sara_app.geometry_kernels.capsule_sets_check`). One call for all people; run by
:meth:`SsmVerifier.verify <sara_app.safety.ssm.SsmVerifier.verify>`, compared with the Python
composition of the same kernels in ``tests/ssm_reference.py``. Numba's cache checks only this
file: the source digests of the files whose kernels it calls are a closure variable.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit, types

from sara_app import geometry_kernels
from sara_app.geometry_kernels import capsule_sets_check
from sara_app.human import reach_kernels
from sara_app.human.reach_kernels import ACC, POS, STATIC, person_sets
from sara_app.kernel_types import B1, F8, I8, RO, ROI1, ROI2, WB3, W
from sara_app.safety.contact_kernels import source_digest

__all__ = ["KIND_ARM", "ssm_kernel"]

KIND_ARM = 5
"""Pereira's arm model: its capsules are computed before the call (``arm``)."""

HUMAN = types.Tuple((RO[3], RO[3], RO[2], RO[3], RO[1]))
"""``(y, v (H, J, 3), dv (H, J), widen (H, M, P), age_s (H,))``: ``widen`` the extra radius
per model (in the check's order) and body part."""
CONSTANTS = types.Tuple((STATIC, ACC, POS, types.UniTuple(F8, 2), I8))
"""``(static, acc, pos, (delay_s, delta_y_m), n_limbs)``: ``HumanReach.kernel_constants``."""
ARM = types.Tuple((RO[5], RO[3]))
"""The arm model's capsules per person ``(ends (H, Ke, C, 2, 3), radius (H, K, C))`` (empty
when the check does not use it)."""


def _make_kernel() -> Any:
    """Build :func:`ssm_kernel` with its callees' source digests in the closure."""
    sources = "".join(source_digest(m) for m in (geometry_kernels, reach_kernels))

    @njit(
        B1(HUMAN, CONSTANTS, ROI1, ROI2, ARM, RO[1], RO[4], RO[2], WB3, WB3, W[2]),
        cache=True,
    )  # fmt: skip
    def ssm_kernel(
        human: Any,
        constants: Any,
        codes: np.ndarray,
        part_maps: np.ndarray,
        arm: Any,
        times: np.ndarray,
        robot_ends: np.ndarray,
        robot_radius: np.ndarray,
        free: np.ndarray,
        evaluated: np.ndarray,
        closest: np.ndarray,
    ) -> bool:
        """Eq. "safe if any model is free" for every person: ``codes (M,)`` the models in order
        (``KIND_*`` of :mod:`~sara_app.human.reach_kernels`, :data:`KIND_ARM`), ``part_maps
        (M, P)`` each model's capsule of each body part (a widened part grows its capsule),
        ``times (K+1,)`` from now, robot capsules ``(K, L, 2, 3)``, ``(K, L)``. Writes ``free,
        evaluated (H, M, K)`` (model ``m`` of person ``h`` was checked on interval ``k`` / found
        no contact there) and ``closest (H, M)`` (exact smallest surface distance over the
        intervals it checked, ``inf``: none). Returns whether every person is cleared on every
        interval."""
        H, M, K = free.shape[0], codes.shape[0], times.shape[0] - 1
        widen, age_s = human[3], human[4]
        static, pos = constants[0], constants[2]
        P, C_pos = static[0].shape[0], pos[3].shape[0]
        C_max = max(P, C_pos, arm[1].shape[2])
        buffers = (np.empty(K), np.empty(K), np.empty((1, K, P, 2, 3)), np.empty((1, K, P)),
                   np.empty((1, P, 2, 3)), np.empty((K, P)), np.empty((1, C_pos, 2, 3)),
                   np.empty((1, K, C_pos)))  # fmt: skip
        grown = np.empty((K, C_max))
        extra = np.empty(C_max)
        cleared = np.empty(K, np.bool_)
        hit = np.empty(K, np.bool_)
        safe = len(sources) > 0  # the digests tie the cache to the callees
        for h in range(H):
            for m in range(M):
                closest[h, m] = np.inf
                for k in range(K):
                    free[h, m, k] = False
                    evaluated[h, m, k] = False
            for k in range(K):
                cleared[k] = False
            for m in range(M):
                todo = evaluated[h, m]
                for k in range(K):
                    todo[k] = not cleared[k]
                if codes[m] == KIND_ARM:
                    ends, radius = arm[0][h], arm[1][h]
                else:
                    ends, radius, _ = person_sets(codes[m], h, human, age_s[h], times, 0, K,
                                                  constants, buffers)  # fmt: skip
                C = radius.shape[1]
                widened = False
                for p in range(P):
                    widened = widened or widen[h, m, p] != 0.0
                if widened:  # a capsule grows by the largest widening of the parts it holds
                    for c in range(C):
                        extra[c] = 0.0
                    for p in range(P):
                        c, w = part_maps[m, p], widen[h, m, p]
                        if extra[c] == extra[c] and (w > extra[c] or w != w):
                            extra[c] = w
                    for x in range(radius.shape[0]):
                        for c in range(C):
                            grown[x, c] = radius[x, c] + extra[c]
                    radius = grown[: radius.shape[0], :C]
                closest[h, m] = capsule_sets_check(ends, radius, robot_ends, robot_radius, todo,
                                                   hit)  # fmt: skip
                done = True
                for k in range(K):
                    free[h, m, k] = todo[k] and not hit[k]
                    cleared[k] = cleared[k] or free[h, m, k]
                    done = done and cleared[k]
                if done:
                    break
            for k in range(K):
                safe = safe and cleared[k]
        return safe

    return ssm_kernel


ssm_kernel = _make_kernel()
