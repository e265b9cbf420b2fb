"""Power and force limiting check (Thumm et al. 2024 eq. 6-7, 47-48): the PFL verdict of one
trajectory.

``c_safe,i,j = ~contact  |  (free & T_i < T_free,i^j)  |  (clamped & T_i < T_clamp,i^j)`` for
every interval ``k``, robot link ``i`` and body part ``j`` (eq. 7), with the contact classes of
:mod:`sara_app.safety.contact` and ``T_i`` the link's energy over the interval
(:mod:`sara_app.robot.energy`): :meth:`PflCheck.check` takes it as given (an interval bound
``(K, L)``, or Thumm et al. 2024's eq. 47-48 end samples); :meth:`PflCheck.check_trajectory` bounds
it between the samples from ``|q''|`` and the shield (:mod:`sara_app.safety.pfl_shield`) with the
exact path-speed peak. A clamped stack of body parts (virtual body part) gets the smallest
constrained threshold of its members.

Several human-set models and people against one trajectory, merged per entry, are the
shield's compiled check (:mod:`sara_app.safety.pfl_cycle`); :meth:`PflCheck.check` is the check
of one set of human capsules given by the caller.

Usage (built once per cell, :meth:`PflCheck.check` every control cycle)::

    pfl = PflCheck(model, skeleton("full").parts)               # thresholds_thumm2024, blunt links
    res = pfl.check(r_ends, r_radius, s_ends, p1_dot, omega, dt,
                    h_ends, h_radius, T_world_box, half_extents_m, energy_J)
    res.safe_all  # bool: eq. 6

or :meth:`PflCheck.check_trajectory` from ``q, q_dot, qd_bound, t`` (it runs the robot occupancy
and :class:`~sara_app.robot.energy.LinkMotion` itself).

Inputs of :meth:`PflCheck.check` (world frame; m, s, J; ``K`` intervals, ``L = model.n_links``
capsule links in ``model.link_names`` order, ``P`` body parts in ``part_names`` order, ``B``
boxes):

==================  ====================  ======================================================
``r_ends``          ``(K, L, 2, 3)``      link capsule over each interval (RobotOccupancy)
``r_radius``        ``(K, L)``
``s_ends``          ``(K+1, L, 2, 3)``    link capsules at the samples (radius model.radius_m)
``p1_dot, omega``   ``(K+1, L, 3)``       velocity of ``s_ends[..., 0, :]``; angular velocity
``dt``              ``(K,)``              interval lengths; ``eps_v`` from the joint limits
``h_ends``          ``(K, P, 2, 3)``      human reachable capsule of each body part (a leading
``h_radius``        ``(K, P)``            axis of 1 is broadcast over the K intervals)
``T_world_box``     ``(B, 4, 4)``         environment boxes (B may be 0)
``half_extents_m``  ``(B, 3)``
``energy_J``        ``(K, L)``            interval energy bounds (or ``(K+1, L)`` samples,
                                          eq. 47-48, or ``(K, 2, L)``)
==================  ====================  ======================================================

Shape errors raise :class:`InputError` (a configuration bug); non-finite VALUES never raise: a
NaN capsule means possible contact (and clamping unless the robot provably cannot clamp), a NaN
velocity disables the velocity relaxation, a NaN energy fails eq. 7; so the verdict is unsafe
and the shield keeps its failsafe. :meth:`PflCheck.check_trajectory` returns an unsafe verdict
for a non-finite trajectory.

Buffers: :class:`LinkMotion` keeps its sample buffers (its outputs are views, valid until its
next call); the classification allocates its (small) arrays per call, and the
:class:`PflResult` arrays are fresh and may be kept.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from sara_app.errors import InputError
from sara_app.robot.energy import (
    LinkMotion,
    bounded_interval_energy_J,
    interval_energy_J,
)
from sara_app.robot.model import RobotModel
from sara_app.robot.occupancy import RobotOccupancy
from sara_app.safety.contact import (
    CLASS_NAMES,
    ContactClassifier,
    ContactResult,
)
from sara_app.safety.pfl_kernels import verdict_kernel
from sara_app.safety.thresholds import (
    ThresholdSet,
    diameters_m,
    load_thresholds,
    threshold_arrays,
)
from sara_app.safety.topology import human_safe_matrix, unclampable_matrix
from sara_app.safety.velocity_error import VelocityErrorBound


@dataclass(frozen=True)
class PflResult:
    """Verdict and details; arrays ``(K, L, P)`` unless noted.

    ``safe``: eq. 7; ``safe_interval (K,)``; ``safe_all``: eq. 6; ``cls`` (int8, names in
    ``CLASS_NAMES``); ``threshold_J``: the threshold that applies (constrained one, min over the
    stack, where clamping is possible; else the unconstrained one); ``energy_J (K, L)``: eq.
    47-48 interval energy; ``margin_J = threshold_J - energy_J`` (negative: too fast);
    ``contact``: the full :class:`ContactResult`.

    Per interval and link ``(K, L)``: ``allowed_J`` the smallest threshold over the body parts
    the link can touch (``inf`` without contact) and ``limiting_part`` the index of that part
    (-1 without contact; its class is ``cls[k, i, limiting_part]``). For speed scaling: a
    path-consistent slow-down by ``a`` scales the energies by ``a^2``, so ``sqrt(allowed_J /
    energy_J)`` is a CANDIDATE factor only: slower links may lose the velocity relaxation (a
    clamping class, a lower threshold), so the slower trajectory must be checked again.
    """

    safe: np.ndarray
    safe_interval: np.ndarray
    safe_all: bool
    cls: np.ndarray
    threshold_J: np.ndarray
    energy_J: np.ndarray
    margin_J: np.ndarray
    contact: ContactResult
    allowed_J: np.ndarray
    limiting_part: np.ndarray
    energy_known: bool = True
    """False: no link could touch anybody, so the check skipped the link energies
    (``energy_J`` and ``margin_J`` are NaN; :meth:`PflShield.with_energies` fills them for
    display)."""

    @property
    def class_names(self) -> tuple[str, ...]:
        return CLASS_NAMES


def _interval_count(r_radius: np.ndarray, dt: np.ndarray) -> int:
    """``K`` from ``r_radius (K, L)``; raises :class:`InputError` unless ``dt`` is ``(K,)``."""
    K = r_radius.shape[0] if np.ndim(r_radius) == 2 else -1
    if np.shape(dt) != (K,):
        raise InputError(f"dt has shape {np.shape(dt)}; expected ({K},)")
    return K


class PflCheck:
    """The PFL check for one robot and one set of body parts (one or more humans).

    ``part_names (P,)``: skeleton body-part names (may repeat for several humans; then give
    ``human_index (P,)``). ``thresholds``: a :class:`ThresholdSet` or its name. ``link_shapes``:
    contact shape per link name (default blunt; set the tool link's shape). ``unclampable_pairs``
    overrides the robot's declared pairs (:mod:`sara_app.safety.topology`). Relaxation switches
    as in :class:`ContactClassifier`.
    """

    def __init__(
        self,
        model: RobotModel,
        part_names: Sequence[str],
        *,
        thresholds: ThresholdSet | str = "thresholds_thumm2024",
        link_shapes: Mapping[str, str] | None = None,
        human_index: Sequence[int] | np.ndarray | None = None,
        unclampable_pairs: Sequence[tuple[str, str]] | None = None,
        relax_velocity: bool = True,
        relax_diameter: bool = True,
        relax_topology: bool = True,
        multi_body: bool = True,
    ) -> None:
        ts = load_thresholds(thresholds) if isinstance(thresholds, str) else thresholds
        self.model, self.thresholds = model, ts
        self.part_names = tuple(part_names)
        self.n_links, self.n_parts = model.n_links, len(self.part_names)
        self.T_free, self.T_clamp = threshold_arrays(
            ts, model.link_names, self.part_names, link_shapes
        )
        self.classifier = ContactClassifier(
            unclampable_matrix(model.name, model.link_names, unclampable_pairs),
            human_safe_matrix(self.part_names, human_index),
            diameters_m(ts, self.part_names),
            relax_velocity=relax_velocity,
            relax_diameter=relax_diameter,
            relax_topology=relax_topology,
            multi_body=multi_body,
        )
        self.velocity_error = VelocityErrorBound(model)
        self.occupancy = RobotOccupancy(model)
        self.motion = LinkMotion(model, self.occupancy)
        self._s_radius = np.asarray(model.radius_m, dtype=float)
        self._warm_up()

    def _warm_up(self) -> None:
        """One check at construction with every body part on the robot's first link (contact,
        clamping against a box under it): the compiled kernels' first-call dispatch (about a
        millisecond) happens here, not in the first control cycle."""
        q = np.zeros((3, self.model.n_dof))
        t = np.array([0.0, 0.01, 0.02])
        ends = self.occupancy.link_ends(q[:1])[0]
        h_ends = np.broadcast_to(ends[-1], (2, self.n_parts, 2, 3)).copy()
        T_box = np.eye(4)[None].copy()
        T_box[0, :3, 3] = ends[-1, 0]
        bound = np.full((2, self.model.n_dof), 0.1)
        self.check_trajectory(
            q, np.zeros_like(q), bound, t, h_ends, np.full((2, self.n_parts), 0.05), T_box,
            np.full((1, 3), 0.05), qdd_bound=bound,
        )  # fmt: skip

    def check(
        self,
        r_ends: np.ndarray,
        r_radius: np.ndarray,
        s_ends: np.ndarray,
        p1_dot: np.ndarray,
        omega: np.ndarray,
        dt: np.ndarray,
        h_ends: np.ndarray,
        h_radius: np.ndarray,
        T_world_box: np.ndarray,
        half_extents_m: np.ndarray,
        energy_J: np.ndarray,
        *,
        eps_v: np.ndarray | None = None,
    ) -> PflResult:
        """Eq. 6-7 over all intervals, links and body parts (inputs in the module docstring).

        ``eps_v (K, L)`` m/s overrides the Thm VI.2 error bound, which is by default computed
        from ``dt`` and the joint limits (see :meth:`eps_from_bounds` for tighter values).
        """
        K = _interval_count(r_radius, dt)
        # the classifier checks the other shapes (human capsules (1, P): every interval)
        E_int = self._interval_energies(energy_J, K)
        if eps_v is None:
            eps_v = self.velocity_error.eps_v(dt)
        elif np.shape(eps_v) != (K, self.n_links):
            raise InputError(f"eps_v has shape {np.shape(eps_v)}; expected ({K}, {self.n_links})")
        c = self.classifier.classify(
            r_ends, r_radius, s_ends, self._s_radius, p1_dot, omega, eps_v,
            h_ends, h_radius, T_world_box, half_extents_m,
        )  # fmt: skip
        return self._verdict(c, E_int)

    def _interval_energies(self, energy_J: np.ndarray, K: int) -> np.ndarray:
        """``(K, L)`` interval energies from the forms :meth:`check` accepts."""
        E = np.asarray(energy_J, dtype=float)
        if E.shape == (K, self.n_links):
            return E.copy()
        if E.shape == (K + 1, self.n_links):
            return interval_energy_J(E)
        if E.shape == (K, 2, self.n_links):
            return E.max(axis=1)
        raise InputError(
            f"energy_J has shape {E.shape}; expected ({K}, {self.n_links}) (interval bounds), "
            f"({K + 1}, {self.n_links}) (samples) or ({K}, 2, {self.n_links})"
        )

    def eps_from_bounds(
        self,
        dt: np.ndarray,
        qd_bound: np.ndarray,
        qdd_bound: np.ndarray | None = None,
        qddd_bound: np.ndarray | None = None,
    ) -> np.ndarray:
        """Thm VI.2 error ``(K, L)`` m/s from per-interval joint bounds ``(K, n)`` (rad/s,
        rad/s^2, rad/s^3; acceleration and jerk default to the joint limits). With the
        Panda's jerk limits a 10 ms interval gives ~0.5 m/s at the hand: pass the trajectory's
        own bounds or use short intervals, or the velocity relaxation rarely applies."""
        lim = self.model.limits
        qdd = lim.a_max if qdd_bound is None else qdd_bound
        qddd = lim.j_max if qddd_bound is None else qddd_bound
        return self.velocity_error.eps_from_bounds(dt, qd_bound, qdd, qddd)

    def _verdict(self, c: ContactResult, E_int: np.ndarray, known: bool = True) -> PflResult:
        K, L, P = c.cls.shape
        thr, margin = np.empty((2, K, L, P))
        safe = np.empty((K, L, P), dtype=bool)
        safe_k = np.empty(K, dtype=bool)
        allowed = np.empty((K, L))
        part = np.empty((K, L), dtype=np.int64)
        verdict_kernel(
            c.stack, c.cls, c.contact, self.T_clamp, self.T_free, E_int,
            thr, margin, safe, safe_k, allowed, part,
        )  # fmt: skip
        return PflResult(
            safe, safe_k, bool(safe_k.all()), c.cls, thr, E_int, margin, c, allowed, part, known
        )

    def check_trajectory(
        self,
        q: np.ndarray,
        q_dot: np.ndarray,
        qd_bound: np.ndarray,
        t: np.ndarray,
        h_ends: np.ndarray,
        h_radius: np.ndarray,
        T_world_box: np.ndarray,
        half_extents_m: np.ndarray,
        qdd_bound: np.ndarray | None = None,
    ) -> PflResult:
        """:meth:`check` of a sampled joint trajectory: ``q, q_dot (K+1, n)`` at times ``t
        (K+1,)``, ``qd_bound (K, n)`` rigorous speed bounds per interval (e.g. a
        ``ShieldedTrajectory``'s ``q, v, v_bound, times``); ``qdd_bound (K, n)`` (its
        ``a_bound``; default the joint acceleration limits) bounds ``|q''|`` over each
        interval: it tightens the Thm VI.2 error (jerk from the joint limits) and bounds the
        link energies BETWEEN the samples
        (:func:`~sara_app.robot.energy.bounded_interval_energy_J`)."""
        q, q_dot, qd_bound, t = (np.asarray(a, dtype=float) for a in (q, q_dot, qd_bound, t))
        try:
            if not math.isfinite(float(q_dot.sum())):
                raise InputError("q_dot is not finite")
            r_ends, r_radius = self.occupancy.intervals(q, qd_bound, t)
        except InputError:
            if all(np.isfinite(a).all() for a in (q, q_dot, qd_bound, t)):
                raise  # a shape or ordering error: the caller's bug
            # a non-finite trajectory: contact with everything, the verdict is unsafe
            K = qd_bound.shape[0]
            r_ends = np.full((K, self.n_links, 2, 3), np.nan)
            r_radius = np.full((K, self.n_links), np.nan)
        samples = self.motion.evaluate(q, q_dot)
        dt = t[1:] - t[:-1]
        qdd = self.model.limits.a_max if qdd_bound is None else np.asarray(qdd_bound, float)
        qdd = np.broadcast_to(np.abs(qdd), qd_bound.shape)
        energy = bounded_interval_energy_J(self.motion, q, samples.energy_J, qdd, dt)
        return self.check(
            r_ends, r_radius, samples.ends, samples.p1_dot, samples.omega, dt,
            h_ends, h_radius, T_world_box, half_extents_m, energy,
            eps_v=self.eps_from_bounds(dt, qd_bound, qdd_bound),
        )  # fmt: skip
