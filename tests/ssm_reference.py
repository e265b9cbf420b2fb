"""The SSM check composed in Python: per person and model, the model's sets from
:meth:`SsmVerifier.occupancy <sara_app.safety.ssm.SsmVerifier.occupancy>` (the reach models'
own entry points), widened per capsule with :func:`~sara_app.human.widening.per_capsule`,
checked with :func:`~sara_app.geometry_kernels.capsule_sets_check`: the reference of the
compiled :func:`~sara_app.safety.ssm_kernel.ssm_kernel` (tests/test_ssm_kernel.py)."""

from __future__ import annotations

import numpy as np

from sara_app.geometry_kernels import capsule_sets_check
from sara_app.human.reach import MODELS, Occupancy, part_capsules
from sara_app.human.widening import per_capsule
from sara_app.safety.ssm import SsmResult, SsmVerifier


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
) -> SsmResult:
    """:meth:`SsmVerifier.verify` (same inputs, same result)."""
    H, M, K = y.shape[0], len(verifier.models), robot_ends.shape[0]
    rows = [MODELS.index(m) for m in verifier.models]
    maps = [part_capsules(verifier.reach, m) for m in verifier.models]
    free = np.zeros((H, M, K), dtype=bool)
    evaluated = np.zeros((H, M, K), dtype=bool)
    closest = np.full((H, M), np.inf)
    hit = np.empty(K, dtype=bool)
    cleared = np.empty(K, dtype=bool)
    safe = True
    for h in range(H):
        tau = times_s + age_s[h]
        cleared[:] = False
        for m, name in enumerate(verifier.models):
            todo = evaluated[h, m]
            np.logical_not(cleared, out=todo)
            occ = verifier.occupancy(name, y[h : h + 1], v[h : h + 1], dv[h : h + 1], tau[:-1],
                                     tau[1:])  # fmt: skip
            if widen_m is not None and widen_m[h, rows[m]].any():
                extra = per_capsule(widen_m[h, rows[m]], maps[m], occ.radius.shape[-1])
                occ = Occupancy(occ.model, occ.ends, occ.radius + extra, occ.names)
            closest[h, m] = capsule_sets_check(occ.ends[0], occ.radius[0], robot_ends,
                                               robot_radius, todo, hit)  # fmt: skip
            np.greater(todo, hit, out=free[h, m])
            np.logical_or(cleared, free[h, m], out=cleared)
            if cleared.all():
                break
        safe = safe and bool(cleared.all())
    return SsmResult(safe, free, evaluated, closest)
