"""The contact classification in plain numpy: a readable, independent reference of what
:meth:`sara_app.safety.contact.ContactClassifier.classify` computes with its compiled kernels
(Thumm et al. 2024, Sec. VI: unconstrained, environment- and self-constrained contacts with the
velocity, diameter and topology relaxations and multi-body clamping). It reads the classifier's
rules; ``tests/test_contact.py`` compares the two on random scenes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from soa_reference import all_pairs, segment_box_soa

from sara_app.safety.contact import (
    ENV_CONSTRAINED,
    NONE,
    SELF_CONSTRAINED,
    UNCONSTRAINED,
    ContactClassifier,
    ContactResult,
)


def segment_box_closest(
    ends: np.ndarray, T_world_box: np.ndarray, half_extents_m: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest points of segments ``(M, 2, 3)`` and boxes ``(B, 4, 4), (B, 3)``.

    Returns ``(distance (M, B), point_on_segment (3, M, B), point_on_box (3, M, B))``, world
    frame (coordinates first), from :func:`soa_reference.segment_box_soa`.
    """
    M, B = ends.shape[0], T_world_box.shape[0]
    p, q = ends[:, 0].T, ends[:, 1].T
    dist = np.empty((M, B))
    p_seg = np.empty((3, M, B))
    p_box = np.empty((3, M, B))
    for b in range(B):
        dist[:, b], p_seg[:, :, b], p_box[:, :, b] = segment_box_soa(
            p, q, T_world_box[b], half_extents_m[b]
        )
    return dist, p_seg, p_box


def unit(v: np.ndarray) -> np.ndarray:
    """Unit vectors of ``(3, ...)`` (coordinates first); a zero vector gives NaN (no relaxation)."""
    n = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    return v / np.where(n > 0.0, n, np.nan)


@dataclass(frozen=True)
class Motion:
    """Link states at the samples, coordinates first: ``pd``, ``w`` ``(3, K+1, L)``, ``reach``
    ``(K+1, L)`` = radius + capsule length (the lever of Thm VI.1), ``eps_v (K, L)``."""

    pd: np.ndarray
    w: np.ndarray
    reach: np.ndarray
    eps_v: np.ndarray


def speed_bounds(n: np.ndarray, m: Motion) -> tuple[np.ndarray, np.ndarray]:
    """Thm VI.1 at both samples of each interval: min and max of ``n . p_dot`` over a link.

    ``n (3, K, L, X)`` normals for link ``i`` (axis 2) against ``X`` objects. Returns ``(v_min,
    v_max)`` ``(K, L, X)``: the min over both samples of ``n . p1_dot - (r + |p2 - p1|) |n x
    w|`` and the max of the ``+`` form (eq. 25; the lower bound needs the minus, see above).
    """
    lo, hi = [], []
    for sl in (slice(None, -1), slice(1, None)):
        pd, w = m.pd[:, sl, :, None], m.w[:, sl, :, None]
        along = n[0] * pd[0] + n[1] * pd[1] + n[2] * pd[2]
        cx = n[1] * w[2] - n[2] * w[1]
        cy = n[2] * w[0] - n[0] * w[2]
        cz = n[0] * w[1] - n[1] * w[0]
        turn = m.reach[sl][..., None] * np.sqrt(cx * cx + cy * cy + cz * cz)
        lo.append(along - turn)
        hi.append(along + turn)
    return np.minimum(lo[0], lo[1]), np.maximum(hi[0], hi[1])


def closure(adj: np.ndarray) -> np.ndarray:
    """Reflexive-transitive closure of ``(K, P, P)`` boolean adjacency (repeated squaring)."""
    P = adj.shape[-1]
    reach = (adj | np.eye(P, dtype=bool)).astype(np.float32)
    for _ in range(max(1, int(np.ceil(np.log2(max(P, 2)))))):
        reach = np.minimum(reach @ reach, 1.0)
    return reach > 0.0


def classify_reference(
    clf: ContactClassifier,
    r_ends: np.ndarray,
    r_radius: np.ndarray,
    s_ends: np.ndarray,
    s_radius: np.ndarray,
    p1_dot: np.ndarray,
    omega: np.ndarray,
    eps_v: np.ndarray,
    h_ends: np.ndarray,
    h_radius: np.ndarray,
    T_world_box: np.ndarray,
    half_extents_m: np.ndarray,
) -> ContactResult:
    """The numpy implementation of :meth:`classify` (the readable reference the compiled
    path is tested against)."""
    K, L = r_radius.shape
    # One all-pairs segment computation for robot and human capsules of each interval.
    caps = np.concatenate([r_ends, h_ends], axis=1)  # (K, N, 2, 3), N = L + P
    rad = np.concatenate([r_radius, h_radius], axis=1)
    d_ax, s, t = all_pairs(caps)
    gap = d_ax - rad[:, :, None] - rad[:, None, :]  # (K, N, N) surface distances
    d_rh = gap[:, :L, L:]
    contact_s = ~(d_rh > 0.0)
    if not contact_s.any():  # no possible contact at all: nothing to classify
        return clf._no_contact(d_rh)
    stack, diam = stacks(clf, gap[:, L:, L:])
    stack_f = stack.astype(np.float32)
    contact_g = np.einsum("klm,kjm->klj", contact_s.astype(np.float32), stack_f) > 0.0
    p1 = s_ends[:, :, 0, :]
    motion = Motion(
        p1_dot.transpose(2, 0, 1),
        omega.transpose(2, 0, 1),
        s_radius + np.linalg.norm(s_ends[:, :, 1, :] - p1, axis=-1),
        eps_v,
    )
    if T_world_box.shape[0]:
        box = segment_box_closest(caps.reshape(-1, 2, 3), T_world_box, half_extents_m)
        env = env_constrained(clf, box, rad, L, stack_f, diam, motion)
    else:
        env = np.zeros(contact_s.shape, dtype=bool)
    rr = (caps[:, :L], gap[:, :L, :L], s[:, :L, :L], t[:, :L, :L])
    self_ = self_constrained(clf, rr, contact_g, diam, motion)
    clamped = contact_g & (env | self_)
    contact = contact_s | clamped
    cls = np.where(
        ~contact,
        NONE,
        np.where(
            clamped & env, ENV_CONSTRAINED, np.where(clamped, SELF_CONSTRAINED, UNCONSTRAINED)
        ),
    ).astype(np.int8)
    return ContactResult(
        contact, contact_s, env & contact_g, self_ & contact_g, cls, stack, diam, d_rh
    )


def stacks(clf: ContactClassifier, d_hh: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Virtual body parts from the human-human surface distances ``(K, P, P)``."""
    K, P = d_hh.shape[:2]
    if not clf.multi_body:
        stack = np.broadcast_to(np.eye(P, dtype=bool), (K, P, P))
        return stack, np.broadcast_to(clf.diameters_m, (K, P))
    stack = closure(~(d_hh > 0.0) & clf._not_safe_h)
    return stack, stack @ clf.diameters_m


def env_constrained(
    clf: ContactClassifier,
    box: tuple[np.ndarray, np.ndarray, np.ndarray],
    rad: np.ndarray,
    L: int,
    stack_f: np.ndarray,
    diam: np.ndarray,
    motion: Motion,
) -> np.ndarray:
    """``(K, L, P)``: an environment-constrained collision is possible (eq. 10-11, 31, 33).

    ``box``: axis distance ``(K N, B)`` and closest points ``(3, K N, B)`` of every capsule
    (robot first in each interval) to every box.
    """
    K, N = rad.shape
    d_ax, p_c, p_b = box
    B = d_ax.shape[1]
    gap = d_ax.reshape(K, N, B) - rad[:, :, None]
    touch = ~(gap[:, L:] > 0.0)  # body part touches box
    touch_g = np.einsum("kjm,kmb->kjb", stack_f, touch.astype(np.float32)) > 0.0
    d_rb = gap[:, :L]
    can = ~(d_rb > 0.0)  # a link touching the box always may clamp
    if clf.relax_velocity:
        n = unit((p_c - p_b).reshape(3, K, N, B)[:, :, :L])  # on the box, towards the link
        v_min, _ = speed_bounds(n, motion)
        can |= ~(v_min >= motion.eps_v[:, :, None])
    else:
        can = np.ones_like(can)
    pair = touch_g[:, None, :, :] & can[:, :, None, :]  # (K, L, P, B)
    if clf.relax_diameter:
        pair &= ~(d_rb[:, :, None, :] > diam[:, None, :, None])
    return np.asarray(pair.any(axis=-1))


def self_constrained(
    clf: ContactClassifier,
    rr: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    contact_g: np.ndarray,
    diam: np.ndarray,
    motion: Motion,
) -> np.ndarray:
    """``(K, L, P)``: a self-constrained collision is possible (eq. 12-13, 32, 34, 37).

    ``rr``: robot capsules ``(K, L, 2, 3)``, their surface distances and closest-point
    parameters ``(K, L, L)``.
    """
    r_ends, d_rr, s, t = rr
    can = ~clf._no_pair[None] & np.ones(d_rr.shape, dtype=bool)
    if clf.relax_velocity:
        e = r_ends.transpose(2, 3, 0, 1)  # (2, 3, K, L)
        p_i = e[0][..., :, None] + s * (e[1] - e[0])[..., :, None]  # (3, K, i, l)
        p_l = e[0][..., None, :] + t * (e[1] - e[0])[..., None, :]
        n_l = unit(p_i - p_l)  # normal on link l towards link i
        v_min_i, _ = speed_bounds(n_l, motion)
        _, v_max_l = speed_bounds(n_l.transpose(0, 1, 3, 2), motion)
        gap = v_min_i - v_max_l.transpose(0, 2, 1)
        eps = motion.eps_v
        apart = (gap >= eps[:, :, None] + eps[:, None, :]) & (d_rr > 0.0)
        can &= ~apart
    pair = contact_g[:, None, :, :] & can[..., None]  # (K, i, l, P)
    if clf.relax_diameter:
        pair &= ~(d_rr[..., None] > diam[:, None, None, :])
    return np.asarray(pair.any(axis=2))
