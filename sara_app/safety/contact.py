"""Contact classification per interval, robot link and body part (Thumm et al. 2024 Sec. VI).

Inputs (all world frame, metres, seconds; ``K`` intervals, ``L`` robot links, ``P`` body parts,
``B`` environment boxes):

- robot interval capsules ``r_ends (K, L, 2, 3)``, ``r_radius (K, L)`` (each contains the link
  over the whole interval, :meth:`RobotOccupancy.intervals`);
- link states at the ``K+1`` samples: ``s_ends (K+1, L, 2, 3)`` (the link capsules, radius
  ``s_radius (L,)``), ``p1_dot (K+1, L, 3)`` velocity of ``s_ends[..., 0, :]`` and ``omega
  (K+1, L, 3)`` (:meth:`sara_app.robot.energy.LinkMotion.evaluate`);
- ``eps_v (K, L)`` m/s: linearisation error of the projected velocities
  (:class:`~sara_app.safety.velocity_error.VelocityErrorBound`, re-exported here);
- human capsules ``h_ends (K, P, 2, 3)``, ``h_radius (K, P)`` (reachable occupancy per interval);
- boxes ``T_world_box (B, 4, 4)``, ``half_extents_m (B, 3)``.

Rules (``~`` = not; every predicate is written so that NaN input gives the conservative answer):

- contact (eq. 8): the link and body-part capsules are not separated;
- env-constrained (eq. 10-11): the body part touches box ``b`` and no relaxation applies:
  velocity (Thm VI.1 and eq. 25-26, 31): every point of the link moves away from the box along
  the normal ``n`` at the closest points, ``min_samples(n.p1_dot - (r + |p2 - p1|) |n x w|) >=
  eps_v``. Note the MINUS: Thumm et al. 2024 prints ``+`` in eq. 16/22-25, but ``cos(alpha) >= -1``
  gives the lower bound with ``-``; the brute-force test in ``tests/test_contact.py`` checks it.
  Human diameter (eq. 33): the link is farther than the body part's diameter from the box;
- self-constrained (eq. 12-13): the body part also touches another link ``l`` and no
  relaxation applies: topology (eq. 36-37, the pair is declared unclampable), diameter (eq. 34,
  the two links are farther apart than the diameter; Thumm et al. 2024 prints ``<=``, the relaxation
  is ``>``), velocity (eq. 32): along the normal ``n_l`` on link ``l`` towards link ``i``, the
  slowest point of ``i`` is at least as fast as the fastest point of ``l`` plus both links'
  linearisation errors (Thumm et al. 2024 adds one ``eps_v``; each link's velocity has its own
  error);
- multi-body clamping (eq. 39-43): body parts whose occupancies intersect and are not a safe
  pair form stacks. Over-approximation used here: the whole connected component of a body part
  (a superset of every path through it) is its virtual body part, with the summed diameter and
  the union occupancy. The component's analysis contains the single part's (contact with any
  member, boxes touched by any member, larger diameter), so one analysis per component suffices.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from sara_app.errors import InputError, ParameterError
from sara_app.geometry.shape_kernels import below_gaps, pair_gaps
from sara_app.safety.contact_kernels import classify_set
from sara_app.safety.velocity_error import VelocityErrorBound

__all__ = [
    "CLASS_NAMES",
    "ENV_CONSTRAINED",
    "NONE",
    "SELF_CONSTRAINED",
    "UNCONSTRAINED",
    "ContactClassifier",
    "ContactResult",
    "RobotSide",
    "VelocityErrorBound",
]

NONE, UNCONSTRAINED, ENV_CONSTRAINED, SELF_CONSTRAINED = 0, 1, 2, 3
CLASS_NAMES: tuple[str, ...] = ("none", "unconstrained", "env-constrained", "self-constrained")


# --- the classifier --------------------------------------------------------------------------


@dataclass(frozen=True)
class ContactResult:
    """Classification of every (interval, link, body part), arrays ``(K, L, P)`` unless noted.

    ``contact``: the link can touch the part or a clamped stack (virtual body part) containing
    it (eq. 8, 40-43); ``contact_single``: eq. 8 for the part alone; ``env`` / ``self_``: an
    environment- / self-constrained collision through the part's stack is possible; ``cls``
    (int8): 0 none, 1 unconstrained, 2 env-constrained, 3 self-constrained (env wins when both);
    ``stack (K, P, P)``: membership of part ``j``'s virtual body part (itself included; the
    identity, not computed, when no contact is possible at all);
    ``stack_diameter_m (K, P)``; ``distance_m``: link-to-part surface distance (m), exact
    where the capsules may touch or nearly do; for a pair whose bounding spheres are apart the
    compiled path (:meth:`ContactClassifier.classify`) gives the spheres' gap instead, a
    positive lower bound (:func:`~sara_app.geometry.shape_kernels.pair_gaps`).
    """

    contact: np.ndarray
    contact_single: np.ndarray
    env: np.ndarray
    self_: np.ndarray
    cls: np.ndarray
    stack: np.ndarray
    stack_diameter_m: np.ndarray
    distance_m: np.ndarray


MotionArrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""``(s_ends (K+1, L, 2, 3), s_radius (L,), p1_dot (K+1, L, 3), omega (K+1, L, 3), eps_v (K,
L))``: the link states at the samples that the clamping rules need."""


class RobotSide:
    """The robot's inputs of one classification (float64, shapes checked by
    :meth:`ContactClassifier.robot_side`) and, computed on first use and then kept, its
    robot-only geometry: link-link surface distances and closest-point parameters ``d_rr,
    s_rr (K, L, L)``, link-box distances ``d_rb (K, L, B)`` and box-to-link vectors ``n_rb
    (K, L, B, 3)`` (the same for every human set checked against this trajectory).

    The link states at the samples (:data:`MotionArrays`) may be deferred: ``motion`` a
    function that returns them, called by :meth:`need_motion` when a human set may touch a
    link (without a possible contact the classification needs only the interval capsules)."""

    def __init__(
        self,
        r_ends: np.ndarray,
        r_radius: np.ndarray,
        motion: MotionArrays | Callable[[], MotionArrays],
        T_world_box: np.ndarray,
        half_extents_m: np.ndarray,
    ) -> None:
        self.r_ends, self.r_radius = r_ends, r_radius
        self.T_world_box, self.half_extents_m = T_world_box, half_extents_m
        self.K, self.L = r_radius.shape
        self.B = T_world_box.shape[0]
        self._motion = motion
        self.s_ends = self.s_radius = self.p1_dot = self.omega = self.eps_v = _NONE
        if not callable(motion):
            self._set_motion(motion)
        self._geometry: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
        self.owner: object = None
        """The classifier whose :meth:`ContactClassifier.robot_side` made this (its switches
        and topology shape the cached clamping predicates)."""
        self.can_box = _unknown((self.K, self.L, self.B))
        """Lazily filled: link ``i`` may clamp against box ``b`` on interval ``k`` (1/0; -1 not
        evaluated; -2 not evaluated and their distance not computed yet), shared by the human
        sets classified against this robot side."""
        self.can_link = _unknown((self.K, self.L, self.L))
        """Lazily filled: links ``i, l`` may close on a body part on interval ``k`` (as
        :attr:`can_box`)."""

    @property
    def has_motion(self) -> bool:
        """Whether the link states are known (given, or :meth:`need_motion` was called)."""
        return not callable(self._motion)

    def need_motion(self) -> None:
        """Obtain the deferred link states (once); raises :class:`InputError` on wrong shapes."""
        if callable(self._motion):
            self._set_motion(self._motion())

    def _set_motion(self, motion: MotionArrays) -> None:
        K, L = self.K, self.L
        arrays = [np.asarray(a, dtype=np.float64) for a in motion]
        _check_shapes(
            ("s_ends", "s_radius", "p1_dot", "omega", "eps_v"), arrays,
            ((K + 1, L, 2, 3), (L,), (K + 1, L, 3), (K + 1, L, 3), (K, L)),
            lambda: f"K = {K} intervals, L = {L} links",
        )  # fmt: skip
        self.s_ends, self.s_radius, self.p1_dot, self.omega, self.eps_v = arrays
        self._motion = motion

    def geometry_buffers(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(d_rr, s_rr, d_rb, n_rb)``, allocated on the first call; an entry is filled once
        its cache entry (:attr:`can_link`, :attr:`can_box`) is above -2 (the compiled
        classification computes only the distances its rules need)."""
        if self._geometry is None:
            K, L, B = self.K, self.L, self.B
            d_rr, s_rr = np.empty((2, K, L, L))
            self._geometry = (d_rr, s_rr, np.empty((K, L, B)), np.empty((K, L, B, 3)))
        return self._geometry


_NONE = np.empty(0)


def _unknown(shape: tuple[int, ...]) -> np.ndarray:
    """An int8 cache of 1/0 predicates, all -2 (neither the predicate nor the distance it reads
    known yet); ``np.full`` costs twice this."""
    out = np.empty(shape, dtype=np.int8)
    out.fill(-2)
    return out


def _check_shapes(
    names: Sequence[str],
    arrays: Sequence[np.ndarray],
    want: Sequence[tuple[int, ...]],
    what: Callable[[], str],
) -> None:
    """Raise :class:`InputError` naming the first array whose shape is not the wanted one
    (``what()``: the context for the message, formatted only then: every check pays for it)."""
    for name, a, shape in zip(names, arrays, want):
        if a.shape != shape:
            raise InputError(f"{name} has shape {a.shape}; expected {shape} ({what()})")


class ContactClassifier:
    """Thumm et al. 2024 Sec. VI for fixed robot/human topology; call :meth:`classify` every cycle.

    ``unclampable (L, L)`` bool (G^(r)), ``human_safe (P, P)`` bool (G^(h)), ``diameters_m
    (P,)``. ``relax_velocity`` / ``relax_diameter`` / ``relax_topology`` / ``multi_body`` switch
    the relaxations and the stack analysis (all on by default; off is always more conservative,
    except ``multi_body=False`` which is NOT sound and exists only for tests and comparison).
    """

    def __init__(
        self,
        unclampable: np.ndarray,
        human_safe: np.ndarray,
        diameters_m: np.ndarray,
        *,
        relax_velocity: bool = True,
        relax_diameter: bool = True,
        relax_topology: bool = True,
        multi_body: bool = True,
    ) -> None:
        L, P = unclampable.shape[0], human_safe.shape[0]
        self.diameters_m = np.asarray(diameters_m, dtype=float).copy()
        shapes = {
            "unclampable": (np.shape(unclampable), (L, L)),
            "human_safe": (np.shape(human_safe), (P, P)),
            "diameters_m": (self.diameters_m.shape, (P,)),
        }
        for key, (got, want) in shapes.items():
            if got != want:
                raise ParameterError(f"{key} has shape {got}; expected {want}")
        if not np.array_equal(np.asarray(human_safe, bool), np.asarray(human_safe, bool).T):
            raise ParameterError("human_safe must be symmetric (a safe pair is unordered)")
        if not np.all(self.diameters_m > 0):
            raise ParameterError(f"diameters_m = {self.diameters_m.tolist()}; expected > 0 (m)")
        unclamp = np.asarray(unclampable, bool) if relax_topology else np.zeros((L, L), bool)
        self._no_pair = unclamp | np.eye(L, dtype=bool)  # (i, l) can never self-clamp
        self._not_safe_h = ~np.asarray(human_safe, bool) & ~np.eye(P, dtype=bool)
        self.relax_velocity, self.relax_diameter = relax_velocity, relax_diameter
        self.multi_body = multi_body
        self._identity_views: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def kernel_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(no_pair (L, L), not_safe_h (P, P), diameters_m (P,))`` as the compiled
        classification takes them: pairs of links that never self-clamp (the diagonal and, with
        the topology relaxation, the declared pairs) and pairs of parts that may stack."""
        return self._no_pair, self._not_safe_h, self.diameters_m

    def switches(self) -> tuple[bool, bool, bool]:
        """``(relax_velocity, relax_diameter, multi_body)`` in the compiled order."""
        return self.relax_velocity, self.relax_diameter, self.multi_body

    def classify(
        self,
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
        """Classify; shapes in the module docstring. Never raises on NaN (NaN = worst case).

        :meth:`robot_side` then :meth:`classify_humans` (compiled): robot-human distances
        first (the broad phase: when no link can touch any body part nothing else is
        computed), then one call of :func:`~sara_app.safety.contact_kernels.classify_set`
        (the other distances and the rules). Same result as the numpy reference in
        ``tests/contact_reference.py`` (tested on random scenes, round-off ties aside).
        """
        robot = self.robot_side(
            r_ends, r_radius, s_ends, s_radius, p1_dot, omega, eps_v, T_world_box, half_extents_m
        )
        return self.classify_humans(robot, h_ends, h_radius)

    def robot_side(
        self,
        r_ends: np.ndarray,
        r_radius: np.ndarray,
        s_ends: np.ndarray,
        s_radius: np.ndarray,
        p1_dot: np.ndarray,
        omega: np.ndarray,
        eps_v: np.ndarray,
        T_world_box: np.ndarray,
        half_extents_m: np.ndarray,
    ) -> RobotSide:
        """The robot's inputs of :meth:`classify` (one trajectory) validated once, for several
        :meth:`classify_humans` calls (e.g. one per human-set model); raises
        :class:`InputError` naming the first array of the wrong shape."""
        motion = (s_ends, s_radius, p1_dot, omega, eps_v)
        return self.robot_side_deferred(r_ends, r_radius, motion, T_world_box, half_extents_m)

    def robot_side_deferred(
        self,
        r_ends: np.ndarray,
        r_radius: np.ndarray,
        motion: MotionArrays | Callable[[], MotionArrays],
        T_world_box: np.ndarray,
        half_extents_m: np.ndarray,
    ) -> RobotSide:
        """:meth:`robot_side` with the link states at the samples ``motion`` given, or as a
        function that returns them, called only when some human set may touch a link."""
        arrays = [
            np.asarray(a, dtype=np.float64) for a in (r_ends, r_radius, T_world_box, half_extents_m)
        ]
        L = self._no_pair.shape[0]
        K = arrays[1].shape[0] if arrays[1].ndim == 2 else -1
        B = arrays[2].shape[0] if arrays[2].ndim == 3 else -1
        if K < 1:
            raise InputError(
                f"r_radius has shape {arrays[1].shape}; expected (K, {L}) with K >= 1 intervals"
            )
        _check_shapes(
            ("r_ends", "r_radius", "T_world_box", "half_extents_m"), arrays,
            ((K, L, 2, 3), (K, L), (B, 4, 4), (B, 3)),
            lambda: f"K = {K} intervals, L = {L} links, B boxes",
        )  # fmt: skip
        robot = RobotSide(arrays[0], arrays[1], motion, arrays[2], arrays[3])
        robot.owner = self
        return robot

    def classify_humans(
        self, robot: RobotSide, h_ends: np.ndarray, h_radius: np.ndarray, lo: int = 0,
        hi: int = -1, cap_z: np.ndarray | None = None,
    ) -> ContactResult:  # fmt: skip
        """:meth:`classify` of intervals ``lo:hi`` (``hi = -1``: to the end) of a
        :meth:`robot_side` against human capsules ``h_ends (1|k, P, 2, 3)``, ``h_radius (1|k,
        P)`` (``k = hi - lo``; 1: the same on every interval; a zero stride counts as 1). The
        robot-only distances are computed once per ``robot``. Results are ``(k, ...)``.
        ``cap_z (k, P)``: each part's height bound on each interval (legs a tracker does not
        measure, :mod:`sara_app.human.legs`; ``inf``: none): a link above it cannot touch it."""
        hi = robot.K if hi < 0 else hi
        if robot.owner is not self:
            raise InputError("robot side made by another classifier; call robot_side() here")
        if not 0 <= lo < hi <= robot.K:
            raise InputError(f"interval range {lo}:{hi}; expected 0 <= lo < hi <= {robot.K}")
        k, L, P = hi - lo, robot.L, self._not_safe_h.shape[0]
        h_ends = np.asarray(h_ends, dtype=np.float64)
        h_radius = np.asarray(h_radius, dtype=np.float64)
        if k > 1 and h_ends.ndim == 4 and h_ends.strides[0] == 0:
            h_ends = h_ends[:1]
        if k > 1 and h_radius.ndim == 2 and h_radius.strides[0] == 0:
            h_radius = h_radius[:1]
        for name, a, tail in (("h_ends", h_ends, (P, 2, 3)), ("h_radius", h_radius, (P,))):
            if a.shape[1:] != tail or a.shape[0] not in (1, k):
                raise InputError(
                    f"{name} has shape {a.shape}; expected ({k}, {', '.join(map(str, tail))}) "
                    f"or a leading 1 (P = {P} parts; intervals {lo}:{hi})"
                )
        d_rh = np.empty((k, L, P))
        touch = pair_gaps(robot.r_ends[lo:hi], robot.r_radius[lo:hi], h_ends, h_radius, d_rh)
        if touch and cap_z is not None:
            cap_z = np.asarray(cap_z, dtype=np.float64)
            if cap_z.shape != (k, P):
                raise InputError(f"cap_z has shape {cap_z.shape}; expected ({k}, {P})")
            touch = below_gaps(robot.r_ends[lo:hi], robot.r_radius[lo:hi], cap_z, d_rh)
        if not touch:
            return self._no_contact(d_rh)  # (NaN is contact)
        robot.need_motion()
        contact_s, env, self_, contact = np.empty((4, k, L, P), dtype=bool)
        cls = np.empty((k, L, P), dtype=np.int8)
        stack = np.empty((k, P, P), dtype=bool)
        diam = np.empty((k, P))
        classify_set(
            lo, hi, robot.r_ends, robot.r_radius, robot.T_world_box, robot.half_extents_m,
            *robot.geometry_buffers(), d_rh, h_ends, h_radius,
            robot.s_ends, robot.s_radius, robot.p1_dot, robot.omega, robot.eps_v, self._no_pair,
            self._not_safe_h, self.diameters_m, self.relax_velocity, self.relax_diameter,
            self.multi_body, contact_s, env, self_, contact, cls, stack, diam, robot.can_box,
            robot.can_link,
        )  # fmt: skip
        return ContactResult(contact, contact_s, env, self_, cls, stack, diam, d_rh)

    def _no_contact(self, d_rh: np.ndarray) -> ContactResult:
        """The result when no link can touch any body part on any interval."""
        K = d_rh.shape[0]
        views = self._identity_views.get(K)
        if views is None:  # read-only broadcast views, shared between results
            P = self.diameters_m.shape[0]
            views = self._identity_views[K] = (
                np.broadcast_to(np.eye(P, dtype=bool), (K, P, P)),
                np.broadcast_to(self.diameters_m, (K, P)),
            )
        none = np.zeros(d_rh.shape, dtype=bool)
        cls0 = np.zeros(d_rh.shape, dtype=np.int8)
        return ContactResult(none, none, none, none, cls0, views[0], views[1], d_rh)
