"""The compiled PFL check of one trajectory against every person with every model, merged per
entry (Thumm et al. 2024 eq. 6-7), model after model, in one call: per model the people's
capsules over the intervals still unproved (each person's sets from that person's measurement
time), the contact classification (eq. 8-13, 39-43) with the link states obtained on the first
possible contact, then the per-entry merge; the speed scaling's path speeds from the verdict.
Run by :func:`~sara_app.safety.pfl_cycle_kernels.cycle_kernel`; compared with the Python
composition of the same kernels in ``tests/pfl_reference.py`` (the same bits). Numba's cache
checks only this file, so the source digests of every file whose kernels it calls are a closure
variable (as in :mod:`sara_app.safety.contact_kernels`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

from sara_app.geometry import shape_kernels
from sara_app.geometry.shape_kernels import below_gaps, pair_gaps
from sara_app.human import reach_kernels
from sara_app.human.reach_kernels import (
    ACC,
    KIND_ACC,
    KIND_ISO,
    KIND_POS,
    KIND_VEL,
    POS,
    STATIC,
    person_sets,
)
from sara_app.kernel_types import B1 as _b1
from sara_app.kernel_types import F8 as _f8
from sara_app.kernel_types import I8 as _i8
from sara_app.kernel_types import RO as _RO
from sara_app.kernel_types import ROB2 as _ROB2
from sara_app.kernel_types import ROC2 as _ROC2
from sara_app.kernel_types import ROCI2 as _ROCI2
from sara_app.kernel_types import ROI1 as _ROI1
from sara_app.kernel_types import ROI2 as _ROI2
from sara_app.kernel_types import WB1 as _WB1
from sara_app.kernel_types import WB3 as _WB3
from sara_app.kernel_types import WC2 as _WC2
from sara_app.kernel_types import WC3 as _WC3
from sara_app.kernel_types import WI1 as _WI1
from sara_app.kernel_types import WI2 as _WI2
from sara_app.kernel_types import WI8_3 as _WI83
from sara_app.kernel_types import W as _W
from sara_app.kernel_types import source_digest
from sara_app.robot import crba_kernels, energy, occupancy_kernels
from sara_app.robot.shielded_kernels import frames
from sara_app.safety import contact_kernels, pfl_kernels, pfl_link_states
from sara_app.safety.contact_kernels import classify_set
from sara_app.safety.pfl_kernels import (
    merge_kernel,
    speed_kernel,
    stuck_kernel,
    summary_kernel,
    verdict_kernel,
)
from sara_app.safety.pfl_link_states import path_states_kernel

__all__ = [
    "KIND_ACC",
    "KIND_ISO",
    "KIND_POS",
    "KIND_VEL",
    "STATE_SIZE",
    "check_buffers",
    "check_results",
    "fused_kernel",
]

STATE_SIZE = 7
"""``state (7,)`` int64: models evaluated, unproved range ``lo, hi``, link states known (0/1),
merged (0/1: a second model was added), eq. 6 holds (0/1), stuck (0/1: an unsafe entry of
interval 0 whose link is already too fast at the current state)."""


ROBOT = types.Tuple((_RO[4], _RO[2], _RO[3], _RO[2], _RO[1]))
"""``(r_ends (K, L, 2, 3), r_radius (K, L), T_world_box (B, 4, 4), half_extents_m (B, 3),
s_radius (L,))``."""
GEOMETRY = types.Tuple((_W[3], _W[3], _W[3], _W[4], _WI83, _WI83))
"""Robot-only geometry scratch ``(d_rr, s_rr (K, L, L), d_rb (K, L, B), n_rb (K, L, B, 3),
can_box (K, L, B), can_link (K, L, L))`` (the caches set to -2 by the caller per check)."""
TRAJECTORY = types.Tuple((_RO[2], _RO[2], _RO[1], _RO[1], _RO[1], _RO[2], _RO[2]))
"""``(q, dq (S, n), sd (S,), sd_max (K,), times (S,), v_bound, a_bound (K, n))``."""
LINK_CONSTANTS = types.Tuple(
    (_RO[2], _ROI1, _RO[3], _ROI1, _ROI1, _RO[3], _ROCI2, _ROC2, _WC2)
    + (_RO[2], _RO[2], _ROI1, _ROI1, _ROI1, _RO[2])
)
""":class:`~sara_app.safety.pfl_link_states.PathLinkStates`' constants in
``path_states_kernel``'s order (jerk limits, kinematics, CRBA, supports, jerk bound)."""
LINK_BUFFERS = types.Tuple(
    (_W[2], _W[2], _W[2], _W[1], _WB1, _W[4], _WC3, _W[4], _W[2], _W[2], _W[3], _W[3])
    + (_W[2], _W[2], _W[1])
)
"""Its buffers for ``S`` samples (outputs: ``T`` energies at index 9, ``E_int`` at 12)."""
RULES = types.Tuple((_ROB2, _ROB2, _RO[1], _RO[2], _RO[2]))
"""``(no_pair (L, L), not_safe_h (P, P), diameters_m (P,), T_clamp, T_free (L, P))`` over the
body parts of every person (``P`` here and in the groups below: ``H`` people's parts, person
``h``'s at ``h P_1 .. (h+1) P_1``; :func:`~sara_app.safety.pfl_cycle.rules_for`)."""
HUMAN = types.Tuple((_RO[3], _RO[3], _RO[2], _RO[3], _RO[1], _RO[3]))
"""``H`` people: ``(y (H, J, 3), v (H, J, 3), dv (H, J), widen (H, 4, P), age_s (H,), caps
(H, P, 2))``, ``widen`` the extra radius per model kind (``KIND_*`` rows) and body part
(:mod:`sara_app.human.widening`), ``age_s`` the time since each one's measurement, ``caps``
each part's height bound ``base + rate * tau`` (``base = inf``: none; legs a tracker does not
measure, :mod:`sara_app.human.legs`)."""
MODELS = types.Tuple(
    (RULES, types.UniTuple(_b1, 3), STATIC, ACC, POS, types.UniTuple(_f8, 2), _i8, _ROI2)
)
"""The per-shield constants of a check: ``(rules, (relax_velocity, relax_diameter, multi_body),
static, acc, pos, (delay_s, delta_y_m), n_limbs, part_maps (4, P))``, ``part_maps`` gathering
each kind's capsules per body part."""
SET_BUFFERS = types.Tuple(
    (_W[1], _W[1], _W[5], _W[3], _W[4], _W[2], _W[4], _W[3], _W[4], _W[2], _W[2])
)  # fmt: skip
"""``(t_start, t_end (K,), acc ends (1, K, P, 2, 3), acc radius (1, K, P), static ends (1, P,
2, 3), static radius (K, P), pos ends (1, C, 2, 3), pos radius (1, K, C), gathered h_ends (K,
H P, 2, 3), h_radius (K, H P), cap_z (K, H P))``: one person's sets at a time, gathered for
all ``H``; ``cap_z`` the parts' height bounds per interval."""
CLASSES = types.Tuple((_WB3, _WB3, _WB3, _WB3, _WI83, _WB3, _W[2], _W[3]))
"""A classification ``(contact, contact_single, env, self_, cls (k, L, P), stack (k, P, P),
stack_diameter_m (k, P), distance_m (k, L, P))``."""
VERDICT = types.Tuple((_W[3], _W[3], _WB3, _WB1, _W[2], _WI2, _W[2], _WI83, _WI1, _W[1]))
"""``(threshold_J, margin_J, safe (K, L, P), safe_interval (K,), allowed_J (K, L),
limiting_part (K, L), energy_J (K, L), merged cls (K, L, P), todo scratch (2,), speeds (2,))``:
``speeds`` the speed scaling's path speeds (rad/s) from the verdict (``pfl_scaling``'s
``candidate``: the candidate of the violated entries when eq. 6 fails; ``allowed_speed``: the
speed at which the contacts reach their thresholds when it holds; NaN: not this case)."""


@njit  # calls kernels of other files: compiled into its callers (kernel_types, caching)
def _human_sets(
    kind: int, lo: int, hi: int, times: np.ndarray, human: Any, models: Any, sets: Any
) -> tuple[np.ndarray, np.ndarray]:
    """Every person's capsule per body part for intervals ``lo:hi``, person ``h``'s parts at
    ``h P .. (h+1) P``: ``(1|k, H P, 2, 3)``, ``(k, H P)`` views of the gathered buffers (a
    leading 1: the same capsule axes on every interval). Each person's sets grow from that
    person's measurement time (``times + age_s[h]``; :func:`person_sets`)."""
    widen, age_s = human[3], human[4]
    part_map = models[7][kind]
    constants = (models[2], models[3], models[4], models[5], models[6])
    buffers = (sets[0], sets[1], sets[2], sets[3], sets[4], sets[5], sets[6], sets[7])
    h_ends, h_radius = sets[8], sets[9]
    k, P = hi - lo, part_map.shape[0]
    ke = 1
    for h in range(human[0].shape[0]):
        e_src, r_src, ke = person_sets(kind, h, human, age_s[h], times, lo, hi, constants,
                                       buffers)  # fmt: skip
        o = h * P
        for x in range(ke):
            for p in range(P):
                c = part_map[p]
                for e in range(2):
                    for r in range(3):
                        h_ends[x, o + p, e, r] = e_src[x, c, e, r]
        for x in range(k):
            for p in range(P):
                h_radius[x, o + p] = r_src[x, part_map[p]] + widen[h, kind, p]
    return h_ends[:ke], h_radius[:k]


@njit(cache=True)
def _caps_at(human: Any, times: np.ndarray, lo: int, hi: int, cap_z: np.ndarray) -> bool:
    """``cap_z[x, h P + p]``: person ``h``'s part ``p`` height bound at the end of interval
    ``lo + x`` (``human[5]``, from that person's measurement time); whether any is finite."""
    caps, age_s = human[5], human[4]
    P = caps.shape[1]
    capped = False
    for h in range(caps.shape[0]):
        for p in range(P):
            if caps[h, p, 0] < np.inf:
                capped = True
    if capped:
        for x in range(hi - lo):
            for h in range(caps.shape[0]):
                tau = age_s[h] + times[lo + x + 1]
                for p in range(P):
                    cap_z[x, h * P + p] = caps[h, p, 0] + caps[h, p, 1] * tau
    return capped


@njit(cache=True)
def _no_contact(out: Any, diameters_m: np.ndarray) -> None:
    """``ContactClassifier._no_contact``'s values: no contact, class 0, every part its own
    stack."""
    contact, contact_s, env, self_, cls, stack, diam, _ = out
    k, L, P = cls.shape
    for x in range(k):
        for i in range(L):
            for j in range(P):
                contact[x, i, j] = False
                contact_s[x, i, j] = False
                env[x, i, j] = False
                self_[x, i, j] = False
                cls[x, i, j] = 0
        for j in range(P):
            diam[x, j] = diameters_m[j]
            for m in range(P):
                stack[x, j, m] = j == m


@njit(cache=True)
def _view(out: Any, k: int) -> Any:
    """The first ``k`` intervals of a classification's buffers."""
    a, b, c, d, e, f, g, h = out
    return a[:k], b[:k], c[:k], d[:k], e[:k], f[:k], g[:k], h[:k]


@njit(cache=True)
def _unproved(safe_k: np.ndarray, state: np.ndarray) -> None:
    """``state[1:3]``: first and one past the last interval not proved safe (``K, K``: none)."""
    K = safe_k.shape[0]
    lo, hi = K, K
    for k in range(K):
        if not safe_k[k]:
            if lo == K:
                lo = k
            hi = k + 1
    state[1], state[2] = lo, hi


@njit  # calls kernels of other files: compiled into its callers (kernel_types, caching)
def _speeds(
    sd: np.ndarray, T: np.ndarray, cls: np.ndarray, verdict: Any, state: np.ndarray
) -> None:
    """``state[5:7]`` and ``speeds``: eq. 6, and the speed scaling's inputs (as
    ``pfl_scaling.candidate`` and ``allowed_speed`` compute them from the result; ``T (S, L)``
    the link energies at the samples, row 0 the current state, zero when not needed)."""
    thr, safe, safe_k, E_int, speeds = verdict[0], verdict[2], verdict[3], verdict[6], verdict[9]
    ok = True
    for k in range(safe_k.shape[0]):
        ok = ok and safe_k[k]
    state[5] = ok
    speeds[0] = math.nan
    speeds[1] = math.nan
    if ok:
        speeds[1] = speed_kernel(False, safe, cls, thr, E_int, sd)
        state[6] = 0
    else:
        speeds[0] = speed_kernel(True, safe, cls, thr, E_int, sd)
        E0 = T[0] if state[3] == 1 else np.zeros(T.shape[1])
        state[6] = stuck_kernel(safe, thr, E0)


@njit(cache=True)
def _py_min(a: float, b: float) -> float:
    """Python's ``min(a, b)`` (``a`` unless ``b < a``; NaN as Python treats it)."""
    return b if b < a else a


@njit(cache=True)
def replan_cap(candidate: float, replan: Any, sd: np.ndarray) -> float:
    """The shield's ``_next_cap``: ``min(cut * candidate, cut * min(cap, sd.max()))`` with
    numpy's max (NaN if any sample is NaN); ``candidate`` inf for a replan within the cycle."""
    top = sd[0]
    for x in sd:
        if x != x:
            top = x
            break
        if x > top:
            top = x
    cut, cap = replan[3], replan[1]
    return _py_min(cut * candidate, cut * _py_min(cap, top))


@njit  # calls a kernel of another file: compiled into its one caller, the PFL cycle kernel
def check_buffers(
    K: int, L: int, P: int, people: int, B: int, C: int, n: int, T0: np.ndarray
) -> Any:
    """Fresh buffers of one check of ``K`` intervals against ``people`` people of ``P`` body parts,
    in ``fused_kernel``'s groups."""
    S = K + 1
    geometry = (np.empty((K, L, L)), np.empty((K, L, L)), np.empty((K, L, B)),
                np.empty((K, L, B, 3)), np.full((K, L, B), -2, np.int8),
                np.full((K, L, L), -2, np.int8))  # fmt: skip
    H = frames(S, n, T0)
    links = (np.empty((S, n)), np.empty((S, n)), np.empty((S, n)), np.empty(S),
             np.empty(S, np.bool_), H, np.empty((S, n, n)), np.empty((S, L, 2, 3)),
             np.empty((S, L)), np.empty((S, L)), np.empty((S, L, 3)), np.empty((S, L, 3)),
             np.empty((K, L)), np.empty((K, L)), np.empty(K))  # fmt: skip
    sets = (np.empty(K), np.empty(K), np.empty((1, K, P, 2, 3)), np.empty((1, K, P)),
            np.empty((1, P, 2, 3)), np.empty((K, P)), np.empty((1, C, 2, 3)),
            np.empty((1, K, C)), np.empty((K, people * P, 2, 3)),
            np.empty((K, people * P)), np.empty((K, people * P)))  # fmt: skip
    return geometry, links, sets, classes(K, L, people * P)


@njit(cache=True)
def classes(K: int, L: int, P: int) -> Any:
    """Buffers of one classification (``fused_kernel``'s ``CLASSES`` group)."""
    return (np.empty((K, L, P), np.bool_), np.empty((K, L, P), np.bool_),
            np.empty((K, L, P), np.bool_), np.empty((K, L, P), np.bool_),
            np.empty((K, L, P), np.int8), np.empty((K, P, P), np.bool_), np.empty((K, P)),
            np.empty((K, L, P)))  # fmt: skip


@njit(cache=True)
def check_results(K: int, L: int, P: int) -> Any:
    """Fresh result arrays of one check: ``(slabs, first, verdict, state)`` with ``first`` and
    ``verdict`` (``fused_kernel``'s groups) views of a few ``slabs`` (each array returned to
    Python costs ~0.5 us): bool ``(5, K, L, P)`` contact, contact_single, env, self_, safe;
    float ``(3, K, L, P)`` threshold, margin, distance; int8 ``(2, K, L, P)`` cls, merged cls;
    stack ``(K, P, P)``; stack diameter ``(K, P)``; safe_interval ``(K,)``; float ``(2, K,
    L)`` allowed, energy; limiting part ``(K, L)``."""
    b5 = np.empty((5, K, L, P), np.bool_)
    f3 = np.empty((3, K, L, P))
    i2 = np.empty((2, K, L, P), np.int8)
    stack, diam, safe_k = np.empty((K, P, P), np.bool_), np.empty((K, P)), np.empty(K, np.bool_)
    f2, part = np.empty((2, K, L)), np.empty((K, L), np.int64)
    first = (b5[0], b5[1], b5[2], b5[3], i2[0], stack, diam, f3[2])
    verdict = (f3[0], f3[1], b5[4], safe_k, f2[0], part, f2[1], i2[1], np.empty(2, np.int64),
               np.full(2, np.nan))  # fmt: skip
    state = np.zeros(STATE_SIZE, np.int64)
    state[2] = K
    return (b5, f3, i2, stack, diam, safe_k, f2, part), first, verdict, state


def _make_kernel() -> Any:
    """Build :func:`fused_kernel` with its callees' source digests in the closure."""
    sources = "".join(
        source_digest(m)
        for m in (
            shape_kernels, reach_kernels, crba_kernels, energy, occupancy_kernels,
            contact_kernels, pfl_kernels, pfl_link_states,
        )
    )  # fmt: skip

    @njit(
        _i8(
            ROBOT, GEOMETRY, TRAJECTORY, LINK_CONSTANTS, LINK_BUFFERS, MODELS, HUMAN,
            SET_BUFFERS, _ROI1, _i8, _b1, types.Tuple((_b1, _f8, _f8, _f8)), CLASSES, CLASSES,
            VERDICT, _WI1,
        ),
        cache=True,
    )  # fmt: skip
    def fused_kernel(
        robot: Any,
        geometry: Any,
        trajectory: Any,
        link_constants: Any,
        link_buffers: Any,
        models: Any,
        human: Any,
        sets: Any,
        order: np.ndarray,
        stop: int,
        first_only: bool,
        replan: Any,
        first: Any,
        scratch: Any,
        verdict: Any,
        state: np.ndarray,
    ) -> int:
        """Add the models ``order[state[0]:stop]`` (codes ``KIND_*``; their constants in
        ``models``, see :data:`MODELS`) to an open check until every entry is
        proved or, with ``first_only``, after one, or with ``replan = (on, cap, c_min, cut)``
        after a failing first model that a replan will follow (not stuck and ``cut * min(cap,
        max sd) >= c_min``: a replan's cap, as the shield's ``_next_cap``). Writes
        the first model's classification
        into ``first``, the merged verdict into ``verdict``, the progress into ``state``.
        Returns the index in ``order`` of the model that completed the check (-1: none; -2:
        unproved entries without link energies, which a classification cannot produce)."""
        if len(sources) == 0:  # never: ties the cache to the callees' files
            return -2
        r_ends, r_radius, T_box, half, s_radius = robot
        d_rr, s_rr, d_rb, n_rb, can_b, can_l = geometry
        no_pair, not_safe_h, diameters_m, T_clamp, T_free = models[0]
        relax_velocity, relax_diameter, multi_body = models[1]
        thr, margin, safe, safe_k, allowed, part, E_int, cls_m, todo, speeds = verdict
        times = trajectory[4]
        K = r_radius.shape[0]
        completed = -1
        i = state[0]
        while i < stop:
            lo, hi = state[1], state[2]
            if lo >= hi:
                completed = i
                break
            k = hi - lo
            is_first = state[0] == 0
            he, hr = _human_sets(order[i], lo, hi, times, human, models, sets)
            out = first if is_first else _view(scratch, k)
            contact, contact_s, env, self_, cls, stack, diam, d_rh = out
            touch = pair_gaps(r_ends[lo:hi], r_radius[lo:hi], he, hr, d_rh)
            if touch and _caps_at(human, times, lo, hi, sets[10]):  # links above a bound: apart
                touch = below_gaps(r_ends[lo:hi], r_radius[lo:hi], sets[10][:k], d_rh)
            if not touch:
                _no_contact(out, diameters_m)
            else:
                if state[3] == 0:  # the link states, once per check
                    path_states_kernel(*trajectory, *link_constants, *link_buffers)
                    E_int[:] = link_buffers[12]
                    state[3] = 1
                s_ends, p1_dot, omega, eps = (
                    link_buffers[7],
                    link_buffers[10],
                    link_buffers[11],
                    link_buffers[13],
                )
                classify_set(
                    lo, hi, r_ends, r_radius, T_box, half, d_rr, s_rr, d_rb, n_rb, d_rh, he, hr,
                    s_ends, s_radius, p1_dot, omega, eps, no_pair, not_safe_h, diameters_m,
                    relax_velocity, relax_diameter, multi_body, contact_s, env, self_, contact,
                    cls, stack, diam, can_b, can_l,
                )  # fmt: skip
            state[0] += 1
            if is_first:
                if state[3] == 0:  # no contact possible: the energies do not matter
                    E_int[:] = math.nan
                verdict_kernel(stack, cls, contact, T_clamp, T_free, E_int, thr, margin, safe,
                               safe_k, allowed, part)  # fmt: skip
                _unproved(safe_k, state)
            else:
                if state[4] == 0:
                    cls_m[:] = first[4]
                    state[4] = 1
                if state[3] == 0:
                    return -2
                merge_kernel(stack, cls, contact, T_clamp, T_free, E_int, lo, safe, cls_m, thr,
                             todo)  # fmt: skip
                if todo[0] >= 0:
                    state[1], state[2] = todo[0], todo[1] + 1
                else:
                    state[1], state[2] = K, K
            if state[1] >= state[2]:
                completed = i
                break
            if first_only:
                break
            if replan[0] and state[0] == 1:
                _speeds(trajectory[2], link_buffers[9], first[4], verdict, state)
                if state[6] == 0 and replan_cap(math.inf, replan, trajectory[2]) >= replan[2]:
                    break
            i += 1
        if state[4] == 1:
            summary_kernel(cls_m, thr, E_int, safe, margin, safe_k, allowed, part)
        _speeds(trajectory[2], link_buffers[9], first[4] if state[4] == 0 else cls_m, verdict,
                state)  # fmt: skip
        return completed

    return fused_kernel


fused_kernel = _make_kernel()
