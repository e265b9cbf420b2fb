"""The SSM check composed in Python: per person and model, the model's sets from
:func:`model_sets` (the reach models' own entry points), widened per capsule with
:func:`~sara_app.human.widening.per_capsule`,
checked with :func:`~sara_app.geometry.shape_kernels.capsule_sets_check` (the whole model) and by
brute force per capsule (:func:`~sara_app.geometry.shapes.capsule_distances`: which body parts the
model clears): the reference of the compiled :func:`~sara_app.safety.ssm_kernels.ssm_kernel`
(tests/test_ssm_kernels.py)."""

from __future__ import annotations

import numpy as np

from sara_app.geometry.shape_kernels import capsule_sets_check
from sara_app.geometry.shapes import capsule_distances
from sara_app.human.reach import MODELS, HumanReach, Occupancy, part_capsules
from sara_app.human.widening import per_capsule
from sara_app.safety.ssm import SsmResult, SsmVerifier


def model_sets(
    reach: HumanReach,
    model: str,
    y: np.ndarray,
    v: np.ndarray,
    dv: np.ndarray,
    t_start_s: np.ndarray,
    t_end_s: np.ndarray,
) -> Occupancy:
    """One human's set ``(1, K|1, C, 2, 3)`` of ``model`` for intervals since its measurement,
    from the reach models' own entry points (no input checks: the references see NaNs too)."""
    if model == "vel":
        return reach.vel(y, t_end_s)
    if model == "pos":
        return reach.pos(y, t_end_s)
    if model == "iso13855":
        return reach.iso13855(y, t_end_s)
    if model == "acc":
        return reach.acc(y, v, dv, t_start_s, t_end_s)
    if model == "combined":
        return reach.combined(y, v, dv, t_start_s, t_end_s)
    from sara_app.human.arm import arm_occupancy

    return arm_occupancy(reach, y, t_start_s, t_end_s)


def verify_reference(
    verifier: SsmVerifier,
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
    """:meth:`SsmVerifier.verify` (same inputs, same result). ``caps (H, P, 2)``: a part is
    touched by a link when the model's capsule for it touches the link (brute force) and the
    link's lowest point is not above the part's height bound at the interval's end."""
    H, M, K = y.shape[0], len(verifier.order), robot_ends.shape[0]
    P = verifier.reach.skeleton.n_parts
    rows = [MODELS.index(m) for m in verifier.order]
    maps = [part_capsules(verifier.reach, m) for m in verifier.order]
    free = np.zeros((H, M, K), dtype=bool)
    evaluated = np.zeros((H, M, K), dtype=bool)
    closest = np.full((H, M), np.inf)
    parts = np.zeros((H, K, P), dtype=bool)
    hit = np.empty(K, dtype=bool)
    if caps is None:
        caps = np.stack([np.full((H, P), np.inf), np.zeros((H, P))], axis=2)
    bottoms = robot_ends[..., 2].min(axis=2) - robot_radius  # (K, L)
    for h in range(H):
        tau = times_s + age_s[h]
        for m, name in enumerate(verifier.order):
            todo = ~parts[h].all(axis=1)
            evaluated[h, m] = todo
            yh, vh, dvh = y[h : h + 1], v[h : h + 1], dv[h : h + 1]
            occ = model_sets(verifier.reach, name, yh, vh, dvh, tau[:-1], tau[1:])
            if widen_m is not None and widen_m[h, rows[m]].any():
                extra = per_capsule(widen_m[h, rows[m]], maps[m], occ.radius.shape[-1])
                occ = Occupancy(occ.model, occ.ends, occ.radius + extra, occ.names)
            closest[h, m] = capsule_sets_check(occ.ends[0], occ.radius[0], robot_ends,
                                               robot_radius, todo, hit)  # fmt: skip
            free[h, m] = todo & ~hit
            C = occ.radius.shape[-1]
            ends = np.broadcast_to(occ.ends[0], (K, C, 2, 3))
            radius = np.broadcast_to(occ.radius[0], (K, C))
            for k in np.flatnonzero(todo):
                # brute force: every (capsule, link) pair's exact surface distance
                d = capsule_distances(ends[k], radius[k], robot_ends[k], robot_radius[k])
                touching = ~(d > 0.0)  # (C, L): NaN touches
                cap_z = caps[h, :, 0] + caps[h, :, 1] * tau[k + 1]  # (P,)
                below = ~(bottoms[k][None, :] > cap_z[:, None])  # (P, L)
                parts[h, k] |= ~(touching[maps[m]] & below).any(axis=1)
            if parts[h].all():
                break
    return SsmResult(bool(parts.all()), free, evaluated, closest, parts, verifier.order)
