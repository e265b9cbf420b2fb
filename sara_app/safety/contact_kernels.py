"""The compiled contact classification of PFL (Thumm et al. 2024, "Provably safe human-robot
interaction via reachability analysis and power and force limiting", Sec. VI) and the jerk
coefficients of its velocity error bound: :func:`classify_set` (one robot capsule set against
one set of body-part capsules and the environment's boxes: unconstrained, environment- and
self-constrained contacts with the velocity, diameter and topology relaxations and multi-body
clamping), :func:`classify_kernel` (the same from precomputed distances) and
:func:`jerk_coefficients`. The closest-point geometry they call is
:mod:`sara_app.geometry.shape_kernels`; the readable numpy reference of the classification is
``tests/contact_reference.py``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

from sara_app.geometry import shape_kernels
from sara_app.geometry.shape_kernels import (
    box_axis_gaps,
    box_entry,
    set_gap_interval,
    set_gap_scratch,
    set_neighbours,
    set_pair_entry,
)
from sara_app.kernel_types import B1 as _b1
from sara_app.kernel_types import I8 as _i8l
from sara_app.kernel_types import RO as _RO
from sara_app.kernel_types import ROB2 as _ROB2
from sara_app.kernel_types import ROI1 as _ROI1
from sara_app.kernel_types import W2 as _WF2
from sara_app.kernel_types import W3 as _WF3
from sara_app.kernel_types import W4 as _WF4
from sara_app.kernel_types import WB3 as _WB3
from sara_app.kernel_types import WI8_3 as _WI3
from sara_app.kernel_types import source_digest

# --- compiled classification (numba) ---------------------------------------------------------
# Explicit signatures (read-only 'A'-layout inputs) and cache=True: compiled or loaded from the
# cache at import, never in a control loop. The helpers live in this file (numba's cache does not
# see changes in other files); classify_set, which calls the geometry kernels, carries their
# source digest in its cache key instead.


@njit(cache=True)
def _normal_speed(
    n: tuple[float, float, float],
    state: tuple[float, float, float, float, float, float, float],
    sign: float,
) -> float:
    """Thm VI.1 along unit ``n`` for one link at one sample, ``state = (p1_dot xyz, omega xyz,
    reach)``: ``n . p1_dot + sign * reach |n x omega|`` (``sign`` -1: the slowest point of the
    link, +1: the fastest). Scalars and tuples only: a compiled helper with array arguments
    costs ~10-20 ns per call (reference counting), which made the clamping predicates 4x
    slower."""
    nx, ny, nz = n
    vx, vy, vz, wx, wy, wz, reach = state
    cx = ny * wz - nz * wy
    cy = nz * wx - nx * wz
    cz = nx * wy - ny * wx
    turn = reach * math.sqrt(cx * cx + cy * cy + cz * cz)
    return nx * vx + ny * vy + nz * vz + sign * turn


@njit(cache=True)
def _interval_speed(
    n: tuple[float, float, float],
    a: tuple[float, float, float, float, float, float, float],
    b: tuple[float, float, float, float, float, float, float],
    sign: float,
) -> float:
    """Over an interval (link states ``a``, ``b`` at its two samples) the min (``sign`` -1) or
    max (+1) of :func:`_normal_speed`; NaN if either sample gives NaN (as ``np.minimum``)."""
    va = _normal_speed(n, a, sign)
    vb = _normal_speed(n, b, sign)
    if va != va or vb != vb:
        return np.nan
    return min(va, vb) if sign < 0.0 else max(va, vb)


@njit(cache=True)
def _unit3(x: float, y: float, z: float) -> tuple[float, float, float]:
    """Unit vector; a zero vector gives NaN (no relaxation), as the numpy reference's ``unit``."""
    n = math.sqrt(x * x + y * y + z * z)
    if not n > 0.0:
        n = np.nan
    return x / n, y / n, z / n


@njit  # not cached on its own: it calls shape_kernels; classify_kernel's cache carries it
def _components(
    h_ends: np.ndarray,
    h_radius: np.ndarray,
    gap_k: tuple[int, int],
    not_safe_h: np.ndarray,
    multi_body: bool,
    comp: np.ndarray,
    queue: np.ndarray,
    gaps: tuple[np.ndarray, np.ndarray],
) -> int:
    """Virtual body parts of one interval: ``comp (P,)`` labels the connected components of
    "not separated and not a safe pair" (breadth-first, labels in order of the smallest
    member); without ``multi_body`` every part is its own component. Returns the number of
    components. The parts' human-human distances (``h_ends (Kh, P, 2, 3)``, ``h_radius (Kr,
    P)``, the interval's ``gap_k = (ke, kr)`` made ready by
    :func:`~sara_app.geometry.shape_kernels.set_gap_interval`, ``gaps = (sph, axis)`` its
    scratch) are computed only where the search reads them
    (:func:`~sara_app.geometry.shape_kernels.set_neighbours`): a part already in a component is
    never compared again. For a symmetric relation (the distances are; ``not_safe_h`` is
    checked at construction) the component is the reflexive-transitive closure of the
    reference."""
    P = comp.shape[0]
    sph, axis = gaps
    ke, kr = gap_k
    for j in range(P):
        comp[j] = -1
    n = 0
    for j in range(P):
        if comp[j] >= 0:
            continue
        comp[j] = n
        if multi_body:
            queue[0] = j
            head, tail = 0, 1
            while head < tail:
                a = queue[head]
                head += 1
                tail = set_neighbours(
                    h_ends, h_radius, ke, kr, a, not_safe_h, sph, axis, comp, n, queue, tail
                )
        n += 1
    return n


@njit(cache=True)
def _env_can(
    d: float,
    n: tuple[float, float, float],
    a: tuple[float, float, float, float, float, float, float],
    b: tuple[float, float, float, float, float, float, float],
    eps_v: float,
    relax_velocity: bool,
) -> int:
    """1: a link may clamp against a box over an interval (it touches the box, surface distance
    ``d``, or it does not provably move away from it along the box-to-link vector ``n`` by more
    than ``eps_v``, eq. 31; link states ``a``, ``b`` at the interval's samples); else 0."""
    if not relax_velocity or not d > 0.0:
        return 1
    v_min = _interval_speed(_unit3(n[0], n[1], n[2]), a, b, -1.0)
    return 0 if v_min >= eps_v else 1


@njit(cache=True)
def _self_can(
    d: float,
    gap: tuple[float, float, float],
    a_i: tuple[float, float, float, float, float, float, float],
    b_i: tuple[float, float, float, float, float, float, float],
    a_l: tuple[float, float, float, float, float, float, float],
    b_l: tuple[float, float, float, float, float, float, float],
    eps: float,
) -> int:
    """1: links ``i`` and ``l`` (surface distance ``d``, closest point of ``i`` minus closest
    point of ``l`` ``gap``, states at the interval's samples ``a_*, b_*``) may close on a body
    part: not provably separating along the normal by more than both links' errors ``eps``
    (eq. 32); else 0. The topology and the switch are the caller's."""
    n = _unit3(gap[0], gap[1], gap[2])
    sep = _interval_speed(n, a_i, b_i, -1.0) - _interval_speed(n, a_l, b_l, 1.0)
    return 0 if (sep >= eps and d > 0.0) else 1


@njit(cache=True)
def _state(
    p1_dot: np.ndarray, omega: np.ndarray, reach: np.ndarray, t: int, i: int
) -> tuple[float, float, float, float, float, float, float]:
    """The state tuple of link ``i`` at sample ``t`` for :func:`_normal_speed`."""
    return (
        p1_dot[t, i, 0], p1_dot[t, i, 1], p1_dot[t, i, 2],
        omega[t, i, 0], omega[t, i, 1], omega[t, i, 2], reach[t, i],
    )  # fmt: skip


def _make_classify_kernel(geometry_source: str) -> Any:
    """Build :func:`classify_kernel`. It calls the kernels of
    :mod:`sara_app.geometry.shape_kernels`, and numba's cache checks only the calling kernel's own
    file: the digest of that module's source (``geometry_source``) is a closure variable, which
    numba hashes into the cache key, so a change there recompiles it instead of loading it with
    the old geometry.
    Only strings may be closure variables: numba pickles them into the key, and a compiled
    function pickles with an identity new in every process (a cache miss at every start: 1.5 s
    of compiling in every process that imported this module, until :func:`classify_set` took
    :func:`classify_kernel` as a global)."""

    @njit(
        _b1(
            _RO[3], _RO[4], _WF3, _WF3, _RO[4], _RO[2], _RO[3], _RO[2], _WF3, _WF4, _RO[3], _RO[2],
            _RO[4], _RO[1], _RO[3], _RO[3], _RO[2], _ROB2, _ROB2, _RO[1],
            _b1, _b1, _b1, _WB3, _WB3, _WB3, _WB3, _WI3, _WB3, _WF2, _WI3, _WI3,
        ),
        cache=True,
    )  # fmt: skip
    def classify_kernel(
        d_rh: np.ndarray,
        h_ends: np.ndarray,
        d_rr: np.ndarray,
        s_rr: np.ndarray,
        r_ends: np.ndarray,
        r_radius: np.ndarray,
        T_world_box: np.ndarray,
        half_extents_m: np.ndarray,
        d_rb: np.ndarray,
        n_rb: np.ndarray,
        hb_axis: np.ndarray,
        h_radius: np.ndarray,
        s_ends: np.ndarray,
        s_radius: np.ndarray,
        p1_dot: np.ndarray,
        omega: np.ndarray,
        eps_v: np.ndarray,
        no_pair: np.ndarray,
        not_safe_h: np.ndarray,
        diameters_m: np.ndarray,
        relax_velocity: bool,
        relax_diameter: bool,
        multi_body: bool,
        contact_s: np.ndarray,
        env: np.ndarray,
        self_: np.ndarray,
        contact: np.ndarray,
        cls: np.ndarray,
        stack: np.ndarray,
        diam: np.ndarray,
        can_b: np.ndarray,
        can_l: np.ndarray,
    ) -> bool:
        """The contact classification as loops (``tests/contact_reference.py``: the same in numpy;
        the rules are documented in :mod:`sara_app.safety.contact`); returns whether any contact
        is possible.

        Geometry inputs: the human capsules' ends ``h_ends (Kh, P, 2, 3)`` (their human-human
        gaps computed where the virtual body parts read them, :func:`_components`), surface
        distances robot-human ``d_rh (K, L, P)``, robot capsules ``r_ends (K, L, 2, 3)``,
        ``r_radius (K, L)``, boxes ``T_world_box (B, 4, 4)``, ``half_extents_m (B, 3)``, human
        axis-to-box ``hb_axis (Kh, P, B)`` and the human radii ``h_radius (Kr, P)`` (``Kh, Kr``
        in ``{1, K}``; the surface distance is their difference, as
        :func:`~sara_app.geometry.shape_kernels.box_distances` computes it).
        Link samples: ``s_ends (K+1, L, 2, 3)``, ``s_radius (L,)``, ``p1_dot, omega (K+1, L, 3)``,
        ``eps_v (K, L)``. Outputs ``(K, L, P)``: ``contact_s``, ``env``, ``self_``
        (both restricted to the stack contact), ``contact``, ``cls``; ``stack (K, P, P)``, ``diam
        (K, P)``. Without any possible contact the outputs are the reference's early result.

        Robot-only geometry, computed where a rule first needs it (most pairs never do: in the
        benchmark's braking state 4-15 % of the link pairs and 15-55 % of the link-box entries):
        robot-robot ``d_rr (K, L, L)`` with closest-point parameters ``s_rr`` (on link ``i`` towards
        ``l``), robot-box ``d_rb (K, L, B)`` with box-to-link vectors ``n_rb (K, L, B, 3)``, the
        numbers of :func:`~sara_app.geometry.shape_kernels.set_pair_distances` and
        :func:`~sara_app.geometry.shape_kernels.box_distances`. ``can_b (K, L, B)``, ``can_l (K, L,
        L)`` (int8): -2 distance not computed yet, -1 distance known but the robot-only clamping
        predicate (:func:`_env_can`, :func:`_self_can`) not evaluated yet, 0 no, 1 yes; they
        depend on the robot inputs and the classifier's switches only, so these caches serve every
        human set checked against the same robot inputs.
        """
        if len(geometry_source) == 0:  # never: ties the cache to shape_kernels.py
            return False
        K, L, P = d_rh.shape
        B = d_rb.shape[2]
        anything = False
        for k in range(K):
            for i in range(L):
                for p in range(P):
                    near = not d_rh[k, i, p] > 0.0
                    contact_s[k, i, p] = near
                    contact[k, i, p] = near
                    env[k, i, p] = False
                    self_[k, i, p] = False
                    cls[k, i, p] = 0
                    anything = anything or near
        if not anything:
            for k in range(K):
                for j in range(P):
                    diam[k, j] = diameters_m[j]
                    for m in range(P):
                        stack[k, j, m] = j == m
            return False
        reach = np.empty((K + 1, L))  # lever of Thm VI.1: radius + capsule length
        for t in range(K + 1):
            for i in range(L):
                e = s_ends[t, i]
                dx, dy, dz = e[1, 0] - e[0, 0], e[1, 1] - e[0, 1], e[1, 2] - e[0, 2]
                reach[t, i] = s_radius[i] + math.sqrt(dx * dx + dy * dy + dz * dz)
        comp = np.empty(P, dtype=np.int64)
        queue = np.empty(P, dtype=np.int64)
        gaps = set_gap_scratch(P)
        gap_k = (-1, -1)  # the human set's (ke, kr) the gaps' scratch is ready for
        diam_c = np.empty(P)
        # per link and virtual body part (component): contact through it, clamping verdicts
        contact_g = np.empty((L, P), dtype=np.bool_)
        touch_g = np.empty((P, B), dtype=np.bool_)
        e_ok = np.empty((L, P), dtype=np.bool_)
        work = np.empty((3, 8))  # box_entry's scratch
        s_ok = np.empty((L, P), dtype=np.bool_)
        for k in range(K):
            kh = k if hb_axis.shape[0] == K else 0
            kr = k if h_radius.shape[0] == K else 0
            if multi_body:
                gap_k = set_gap_interval(h_ends, h_radius, k, K, gap_k, gaps[0], gaps[1])
            n_c = _components(h_ends, h_radius, gap_k, not_safe_h, multi_body, comp, queue, gaps)
            for c in range(n_c):
                diam_c[c] = 0.0
            for m in range(P):  # ascending members: the same sum as the closure's row
                diam_c[comp[m]] += diameters_m[m]
            for j in range(P):
                diam[k, j] = diam_c[comp[j]]
                for m in range(P):
                    stack[k, j, m] = comp[j] == comp[m]
            any_k = False
            for i in range(L):  # contact with the stack
                for c in range(n_c):
                    contact_g[i, c] = False
                for m in range(P):
                    if contact_s[k, i, m]:
                        contact_g[i, comp[m]] = True
                        any_k = True
            if not any_k:
                continue
            # environment-constrained (eq. 10-11, 31, 33): the stack touches box b and link i may
            # not provably move away from it
            for c in range(n_c):
                for b in range(B):
                    touch_g[c, b] = False
            for m in range(P):
                for b in range(B):
                    if not hb_axis[kh, m, b] - h_radius[kr, m] > 0.0:
                        touch_g[comp[m], b] = True
            for i in range(L):
                for c in range(n_c):
                    if not contact_g[i, c]:  # no contact through the stack: nothing to clamp
                        continue
                    eo = False
                    for b in range(B):
                        if not touch_g[c, b]:
                            continue
                        if can_b[k, i, b] == -2:
                            box_entry(
                                r_ends, r_radius, T_world_box, half_extents_m, k, k, i, b, work,
                                d_rb, n_rb, True,
                            )  # fmt: skip
                            can_b[k, i, b] = -1
                        if not (relax_diameter and d_rb[k, i, b] > diam_c[c]):
                            if can_b[k, i, b] < 0:
                                n = (n_rb[k, i, b, 0], n_rb[k, i, b, 1], n_rb[k, i, b, 2])
                                can_b[k, i, b] = _env_can(
                                    d_rb[k, i, b], n, _state(p1_dot, omega, reach, k, i),
                                    _state(p1_dot, omega, reach, k + 1, i), eps_v[k, i],
                                relax_velocity,
                                )  # fmt: skip
                            if can_b[k, i, b] == 1:
                                eo = True
                                break
                    so = False
                    for l in range(L):
                        if not contact_g[l, c] or no_pair[i, l]:  # a declared pair never clamps
                            continue
                        if can_l[k, i, l] == -2:
                            first, second = (i, l) if i < l else (l, i)
                            set_pair_entry(r_ends, r_radius, k, k, k, first, second, d_rr, s_rr)
                            can_l[k, i, l] = -1
                            if can_l[k, l, i] == -2:
                                can_l[k, l, i] = -1
                        if not (relax_diameter and d_rr[k, i, l] > diam_c[c]):
                            if can_l[k, i, l] < 0:
                                if not relax_velocity:
                                    can_l[k, i, l] = 1
                                else:
                                    s, t, e = s_rr[k, i, l], s_rr[k, l, i], r_ends
                                    gap = (
                                        e[k, i, 0, 0]
                                        + s * (e[k, i, 1, 0] - e[k, i, 0, 0])
                                        - (e[k, l, 0, 0] + t * (e[k, l, 1, 0] - e[k, l, 0, 0])),
                                        e[k, i, 0, 1]
                                        + s * (e[k, i, 1, 1] - e[k, i, 0, 1])
                                        - (e[k, l, 0, 1] + t * (e[k, l, 1, 1] - e[k, l, 0, 1])),
                                        e[k, i, 0, 2]
                                        + s * (e[k, i, 1, 2] - e[k, i, 0, 2])
                                        - (e[k, l, 0, 2] + t * (e[k, l, 1, 2] - e[k, l, 0, 2])),
                                    )
                                    can_l[k, i, l] = _self_can(
                                        d_rr[k, i, l], gap, _state(p1_dot, omega, reach, k, i),
                                        _state(p1_dot, omega, reach, k + 1, i),
                                        _state(p1_dot, omega, reach, k, l),
                                        _state(p1_dot, omega, reach, k + 1, l),
                                        eps_v[k, i] + eps_v[k, l],
                                    )  # fmt: skip
                            if can_l[k, i, l] == 1:
                                so = True
                                break
                    e_ok[i, c] = eo
                    s_ok[i, c] = so
            for i in range(L):
                for j in range(P):
                    c = comp[j]
                    if not contact_g[i, c]:
                        continue
                    eo, so = e_ok[i, c], s_ok[i, c]
                    env[k, i, j] = eo
                    self_[k, i, j] = so
                    if eo or so:
                        contact[k, i, j] = True
                        cls[k, i, j] = 2 if eo else 3
                    elif contact_s[k, i, j]:
                        cls[k, i, j] = 1
        return True

    return classify_kernel


_GEOMETRY_SOURCE = source_digest(shape_kernels)
classify_kernel = _make_classify_kernel(_GEOMETRY_SOURCE)


def _make_classify_set(geometry_source: str) -> Any:
    """Build :func:`classify_set` (as :func:`_make_classify_kernel`; it calls
    :func:`classify_kernel` as this module's global, never as a closure variable)."""

    @njit(
        _b1(
            _i8l, _i8l, _RO[4], _RO[2], _RO[3], _RO[2], _WF3, _WF3, _WF3, _WF4,
            _RO[3], _RO[4], _RO[2], _RO[4], _RO[1], _RO[3], _RO[3], _RO[2], _ROB2, _ROB2, _RO[1],
            _b1, _b1, _b1, _WB3, _WB3, _WB3, _WB3, _WI3, _WB3, _WF2, _WI3, _WI3,
        ),
        cache=True,
    )  # fmt: skip
    def classify_set(
        lo: int,
        hi: int,
        r_ends: np.ndarray,
        r_radius: np.ndarray,
        T_world_box: np.ndarray,
        half_extents_m: np.ndarray,
        d_rr: np.ndarray,
        s_rr: np.ndarray,
        d_rb: np.ndarray,
        n_rb: np.ndarray,
        d_rh: np.ndarray,
        h_ends: np.ndarray,
        h_radius: np.ndarray,
        s_ends: np.ndarray,
        s_radius: np.ndarray,
        p1_dot: np.ndarray,
        omega: np.ndarray,
        eps_v: np.ndarray,
        no_pair: np.ndarray,
        not_safe_h: np.ndarray,
        diameters_m: np.ndarray,
        relax_velocity: bool,
        relax_diameter: bool,
        multi_body: bool,
        contact_s: np.ndarray,
        env: np.ndarray,
        self_: np.ndarray,
        contact: np.ndarray,
        cls: np.ndarray,
        stack: np.ndarray,
        diam: np.ndarray,
        can_b: np.ndarray,
        can_l: np.ndarray,
    ) -> bool:
        """:func:`classify_kernel` of intervals ``lo:hi`` of one robot trajectory (all its
        arrays over every interval ``K``) against one human set, with the distances it needs
        computed here or in :func:`classify_kernel`: the robot-only ones (``d_rr, s_rr, d_rb,
        n_rb`` over every ``K``, the caches ``can_b, can_l`` say which are known: -2 not yet)
        where a clamping rule first needs them, the human-human ones only where the search
        for the virtual body parts reads them (:func:`_components`: pairs that are not safe,
        with a part not yet in the component) and the human axis-to-box ones only where the
        touch test needs them (:func:`~sara_app.geometry.shape_kernels.box_axis_gaps`): same
        signs, same result.
        ``d_rh (k, L, P)`` (``k = hi - lo``) as :func:`~sara_app.geometry.shape_kernels.pair_gaps`
        gives it; human sets ``(1|k, P, ...)``; outputs ``(k, ...)`` as in
        :func:`classify_kernel`."""
        if len(geometry_source) == 0:  # never: ties the cache to shape_kernels.py
            return False
        P, B = h_radius.shape[1], T_world_box.shape[0]
        hb_axis = np.empty((h_ends.shape[0], P, B))
        box_axis_gaps(h_ends, h_radius, T_world_box, half_extents_m, hb_axis)
        return classify_kernel(
            d_rh, h_ends, d_rr[lo:hi], s_rr[lo:hi], r_ends[lo:hi], r_radius[lo:hi], T_world_box,
            half_extents_m, d_rb[lo:hi], n_rb[lo:hi], hb_axis, h_radius, s_ends[lo : hi + 1],
            s_radius, p1_dot[lo : hi + 1], omega[lo : hi + 1], eps_v[lo:hi], no_pair, not_safe_h,
            diameters_m, relax_velocity, relax_diameter, multi_body, contact_s, env, self_,
            contact, cls, stack, diam, can_b[lo:hi], can_l[lo:hi],
        )  # fmt: skip

    return classify_set


classify_set = _make_classify_set(_GEOMETRY_SOURCE)


@njit(types.void(_RO[2], _RO[2], _RO[2], _ROI1, _ROI1, _RO[2], _RO[1], _WF2), cache=True)
def jerk_coefficients(
    qd: np.ndarray,
    qdd: np.ndarray,
    qddd: np.ndarray,
    order: np.ndarray,
    parent: np.ndarray,
    D: np.ndarray,
    scale: np.ndarray,
    out: np.ndarray,
) -> None:
    """The ``"spatial"`` form of :meth:`VelocityErrorBound.coefficients`, times ``scale (K,)``
    per row: joint bounds ``qd (K, n)``, ``qdd`` and ``qddd`` ``(K|1, n)`` (absolute values
    taken here; one row applies to every interval), joints visited in ``order`` (parents first)
    with ``parent`` (-1: the base), lever matrix ``D (n, L)``; writes ``out (K, L)``."""
    K, n = qd.shape
    W, A, Bj = np.empty(n), np.empty(n), np.empty(n)
    for k in range(K):
        k2 = k if qdd.shape[0] == K else 0
        k3 = k if qddd.shape[0] == K else 0
        for x in range(order.shape[0]):
            j, p = order[x], parent[x]
            w0, a0, b0 = (0.0, 0.0, 0.0) if p < 0 else (W[p], A[p], Bj[p])
            v, a, jj = abs(qd[k, j]), abs(qdd[k2, j]), abs(qddd[k3, j])
            W[j] = w0 + v
            A[j] = a0 + a + v * w0
            Bj[j] = b0 + jj + 2.0 * a * w0 + v * (a0 + w0 * w0)
        for i in range(D.shape[1]):
            acc = 0.0
            for j in range(n):
                acc += (Bj[j] + 3.0 * A[j] * W[j] + W[j] * W[j] * W[j]) * D[j, i]
            out[k, i] = acc * scale[k]
