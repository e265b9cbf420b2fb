"""The compiled SSM check of one shielded trajectory against every person: for each person, the
models in order over the intervals not cleared yet, each model's capsules (:func:`person_sets`,
from that person's measurement time) against the robot's capsules per interval
(:func:`~sara_app.geometry.shape_kernels.capsule_sets_check`).

The verdict is per body part: part ``p`` is clear on interval ``k`` when some model's capsule
for THAT part (``part_maps[m, p]``) is free of the robot there; the interval is clear when every
part is. Every model's capsule of a part contains the part, so this is sound whenever each
model is, and at least as tight as "one model free for the whole person" (Schepp et al. 2022's
rule, which it contains: a free model clears every part). One call for all people; run by
:meth:`SsmVerifier.verify <sara_app.safety.ssm.SsmVerifier.verify>`, compared with the Python
composition of the same kernels in ``tests/ssm_reference.py``. Numba's cache checks only this
file: the source digests of the files whose kernels it calls are a closure variable.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numba import njit, types

from sara_app.geometry import shape_kernels
from sara_app.geometry.shape_kernels import (
    bounding_spheres,
    capsule_sets_check,
    lowest_z,
    segment_closest,
    sphere_gap,
    sphere_slack_m,
)
from sara_app.human import reach_kernels
from sara_app.human.reach_kernels import CONSTANTS, person_sets
from sara_app.kernel_types import B1, RO, ROB3, ROI1, ROI2, WB2, WB3, W, source_digest

__all__ = ["KIND_ARM", "model_verdicts", "ssm_kernel"]

KIND_ARM = 5
"""Pereira's arm model: its capsules are computed before the call (``arm``)."""

HUMAN = types.Tuple((RO[3], RO[3], RO[2], RO[3], RO[1], RO[3]))
"""``(y, v (H, J, 3), dv (H, J), widen (H, M, P), age_s (H,), caps (H, P, 2))``: ``widen`` the
extra radius per model (in the check's order) and body part; ``caps`` each part's height bound
``base + rate * tau`` (m, m/s; ``tau`` the time since the measurement; ``base = inf``: none) of
legs the tracker does not measure (:mod:`sara_app.human.legs`)."""
ARM = types.Tuple((RO[5], RO[3]))
"""The arm model's capsules per person ``(ends (H, Ke, C, 2, 3), radius (H, K, C))`` (empty
when the check does not use it)."""


@njit(types.void(ROB3, ROB3, WB2), cache=True)
def model_verdicts(evaluated: np.ndarray, free: np.ndarray, out: np.ndarray) -> None:
    """Per model, over every person and interval of a check (``evaluated``, ``free (H, M, K)``,
    :class:`~sara_app.safety.ssm.SsmResult`): ``out[0, m]`` model ``m`` was evaluated on all of
    them, ``out[1, m]`` its sets were free on all of them (``out (2, M)``). Compiled: numpy's
    two reductions over two axes cost 3 us of a 50 us cycle."""
    H, M, K = evaluated.shape
    for m in range(M):
        ev, fr = True, True
        for h in range(H):
            for k in range(K):
                ev = ev and evaluated[h, m, k]
                fr = fr and free[h, m, k]
        out[0, m], out[1, m] = ev, fr


@njit  # calls kernels of other files: compiled into its callers (kernel_types, caching)
def _touching(
    ends: np.ndarray, radius: np.ndarray, r_ends: np.ndarray, r_radius: np.ndarray,
    spheres: np.ndarray, r_spheres: np.ndarray, out: np.ndarray,
) -> None:  # fmt: skip
    """``out[c]``: ``-inf`` when capsule ``c`` of ``ends (C, 2, 3)``, ``radius (1, C)`` may
    touch one of the robot's ``r_ends (L, 2, 3)``, ``r_radius (1, L)`` (surface distance <= 0
    or NaN; exact segment distances where their bounding spheres ``spheres (C, 4)``,
    ``r_spheres (L, 4)`` (:func:`~sara_app.geometry.shape_kernels.bounding_spheres`) do not
    tell them apart), else ``inf``: :func:`_lowest_touching` for a set without height bounds, which
    needs only whether, not how low."""
    for c in range(ends.shape[0]):
        out[c] = np.inf
        p, q = ends[c, 0], ends[c, 1]
        for i in range(r_ends.shape[0]):
            if sphere_gap(spheres, c, r_spheres, i) > sphere_slack_m:
                continue
            a, b = r_ends[i, 0], r_ends[i, 1]
            d = segment_closest(p[0], p[1], p[2], q[0], q[1], q[2], a[0], a[1], a[2], b[0], b[1],
                                b[2])[0]  # fmt: skip
            if not d - radius[0, c] - r_radius[0, i] > 0.0:
                out[c] = -np.inf
                break


@njit  # calls kernels of other files: compiled into its callers (kernel_types, caching)
def _lowest_touching(
    ends: np.ndarray, radius: np.ndarray, r_ends: np.ndarray, r_radius: np.ndarray,
    spheres: np.ndarray, r_spheres: np.ndarray, out: np.ndarray,
) -> None:  # fmt: skip
    """``out[c]``: the lowest point of the robot's capsules that capsule ``c`` may touch (as
    :func:`_touching`; ``-inf`` for a NaN link); ``inf``: none. Its own loop: one loop for
    both (asking how low or stopping at the first touch) cost 4-6 us per check without height
    bounds (it compiled worse)."""
    for c in range(ends.shape[0]):
        out[c] = np.inf
        p, q = ends[c, 0], ends[c, 1]
        for i in range(r_ends.shape[0]):
            if sphere_gap(spheres, c, r_spheres, i) > sphere_slack_m:
                continue
            a, b = r_ends[i, 0], r_ends[i, 1]
            d = segment_closest(p[0], p[1], p[2], q[0], q[1], q[2], a[0], a[1], a[2], b[0], b[1],
                                b[2])[0]  # fmt: skip
            if not d - radius[0, c] - r_radius[0, i] > 0.0:
                bottom = lowest_z(a[2], b[2], r_radius[0, i])
                if bottom < out[c]:
                    out[c] = bottom


def _make_kernel() -> Any:
    """Build :func:`ssm_kernel` with its callees' source digests in the closure."""
    sources = "".join(source_digest(m) for m in (shape_kernels, reach_kernels))

    @njit(
        B1(HUMAN, CONSTANTS, ROI1, ROI2, ARM, RO[1], RO[4], RO[2], WB3, WB3, W[2], WB3),
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
        parts: np.ndarray,
    ) -> bool:
        """The per-body-part verdict for every person: ``codes (M,)`` the models in order
        (``KIND_*`` of :mod:`~sara_app.human.reach_kernels`, :data:`KIND_ARM`), ``part_maps
        (M, P)`` each model's capsule of each body part (a widened part grows its capsule),
        ``times (K+1,)`` from now, robot capsules ``(K, L, 2, 3)``, ``(K, L)``. Writes ``free,
        evaluated (H, M, K)`` (model ``m`` of person ``h`` was checked on interval ``k`` / none
        of its capsules touches the robot there), ``closest (H, M)`` (exact smallest surface
        distance over the intervals it checked, ``inf``: none) and ``parts (H, K, P)`` (body
        part ``p`` proved clear on interval ``k``; a part with a height bound, ``human[5]``, is
        clear of the links above it at the interval's end). Returns whether every part of every
        person is clear on every interval."""
        H, M, K = free.shape[0], codes.shape[0], times.shape[0] - 1
        widen, age_s, caps = human[3], human[4], human[5]
        static, pos = constants[0], constants[2]
        P, C_pos = static[0].shape[0], pos[3].shape[0]
        C_max = max(P, C_pos, arm[1].shape[2])
        buffers = (np.empty(K), np.empty(K), np.empty((1, K, P, 2, 3)), np.empty((1, K, P)),
                   np.empty((1, P, 2, 3)), np.empty((K, P)), np.empty((1, C_pos, 2, 3)),
                   np.empty((1, K, C_pos)))  # fmt: skip
        grown = np.empty((K, C_max))
        extra = np.empty(C_max)
        hit = np.empty(K, np.bool_)
        low = np.empty(C_max)
        spheres, r_spheres = np.empty((C_max, 4)), np.empty((robot_ends.shape[1], 4))
        safe = len(sources) > 0  # the digests tie the cache to the callees
        for h in range(H):
            capped = False  # a part with a height bound: the links' heights matter
            for p in range(P):
                capped = capped or caps[h, p, 0] < np.inf
            for m in range(M):
                closest[h, m] = np.inf
                for k in range(K):
                    free[h, m, k] = False
                    evaluated[h, m, k] = False
            cleared = parts[h]  # (K, P): part p proved free on interval k by some model
            for k in range(K):
                for p in range(P):
                    cleared[k, p] = False
            for m in range(M):
                todo = evaluated[h, m]
                for k in range(K):
                    todo[k] = False
                    for p in range(P):
                        todo[k] = todo[k] or not cleared[k, p]
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
                    if not todo[k]:
                        continue
                    free[h, m, k] = not hit[k]
                    if hit[k]:  # which of the model's capsules touch the robot here
                        e_k = ends[k if ends.shape[0] == K else 0]
                        x = k if radius.shape[0] == K else 0
                        r_k, r_ends_k = radius[x : x + 1], robot_ends[k]
                        r_radius_k = robot_radius[k : k + 1]
                        bounding_spheres(e_k, r_k, spheres)
                        bounding_spheres(r_ends_k, r_radius_k, r_spheres)
                        if capped:  # how low: a part is clear of the links above its bound
                            _lowest_touching(e_k, r_k, r_ends_k, r_radius_k, spheres, r_spheres,
                                             low)  # fmt: skip
                        else:
                            _touching(e_k, r_k, r_ends_k, r_radius_k, spheres, r_spheres, low)
                    tau = age_s[h] + times[k + 1]  # a height bound at the interval's end
                    for p in range(P):
                        if hit[k]:  # touched: a link as low as the part's bound (NaN: no bound)
                            z = low[part_maps[m, p]]
                            if z < np.inf and not z > caps[h, p, 0] + caps[h, p, 1] * tau:
                                continue
                        cleared[k, p] = True
                    for p in range(P):
                        done = done and cleared[k, p]
                if done:
                    break
            for k in range(K):
                for p in range(P):
                    safe = safe and cleared[k, p]
        return safe

    return ssm_kernel


ssm_kernel = _make_kernel()
