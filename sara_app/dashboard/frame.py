"""What the dashboard draws for one instant: plain numpy containers, no viser, no bus types.

Shapes: ``J`` skeleton joints, ``B`` bones, ``C`` capsules of one model, ``K`` time intervals of
the shielded trajectory, ``L`` robot links, ``M`` environment boxes. Lengths in m, world frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

EFFECTIVE = "effective"
"""Each person's effective set: per body part the least of the models' capsules for it (the
worker's :func:`~sara_app.runtime.display.effective_set`)."""
MODEL_NAMES: tuple[str, ...] = (EFFECTIVE, "pos", "vel", "acc", "iso13855", "arm", "combined")
"""Human sets the dashboard knows: the effective set and the reachability models (one capsule
group and one toggle each)."""

CONTACT_NONE, CONTACT_UNCONSTRAINED, CONTACT_ENV, CONTACT_SELF = 0, 1, 2, 3
"""Values of :attr:`DisplayFrame.contact_class`: no contact possible, free (unconstrained)
contact, clamping against the environment, clamping between robot links."""


@dataclass
class HumanDisplay:
    """One tracked human.

    ``joint_positions (J, 3)`` (NaN rows for missing joints are skipped), ``bone_pairs (B, 2)``
    int indices into the joints, ``models``: model name (one of :data:`MODEL_NAMES`) to
    ``(ends (C, 2, 3), radius (C,))`` reachable capsules over the whole horizon;
    ``legs_below_m``: the height unmeasured legs stay below over it (None: no bound);
    ``cuts``: model name to ``(C,)`` the height each of its capsules is cut at (the set is the
    capsule's part at or below it; ``inf``: whole; a model not listed: all whole).
    """

    id: str
    joint_positions: np.ndarray
    bone_pairs: np.ndarray
    models: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    legs_below_m: float | None = None
    cuts: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass
class EnvBoxes:
    """Oriented environment boxes: ``T_world_box (M, 4, 4)``, ``half_extents_m (M, 3)``."""

    T_world_box: np.ndarray
    half_extents_m: np.ndarray


CONTACT_CODES: dict[str, int] = {
    "unconstrained": CONTACT_UNCONSTRAINED,
    "env-constrained": CONTACT_ENV,
    "self-constrained": CONTACT_SELF,
}
"""Contact class names of the bus messages to :attr:`DisplayFrame.contact_class` values."""


@dataclass
class LinkEnergy:
    """One robot link's kinetic energy over the shielded trajectory and the PFL threshold that
    applies to it [J]: ``limit_j`` None when the link cannot touch anybody; ``margin_j`` =
    limit - energy; the human, body part, contact class and shape that set the limit."""

    link: str
    energy_j: float
    limit_j: float | None = None
    margin_j: float | None = None
    human_id: str | None = None
    body_part: str | None = None
    contact: str | None = None
    shape: str = "blunt"


@dataclass
class ContactParts:
    """Body parts in possible contact, as capsules along each part's two end joints:
    ``ends (P, 2, 3)``, ``radius (P,)``, ``contact_class (P,)`` (``CONTACT_*`` values)."""

    ends: np.ndarray
    radius: np.ndarray
    contact_class: np.ndarray


@dataclass
class DisplayFrame:
    """Everything the 3D view and the status panel show for one instant.

    - ``t_s``: time stamp of the verdict [s] (x axis of the live plots);
    - ``q (n_dof,)``: robot joint configuration (URDF actuated joint order);
    - ``robot_ends (K, L, 2, 3)``, ``robot_radius (K, L)``: occupancy of the shielded
      trajectory per interval and link; ``verified``: the shield's verdict for it;
    - ``contact_class (K, L)`` int8 or None: one of the ``CONTACT_*`` values per capsule;
    - ``status``: ``mode`` (str), ``safety_mode`` (str), ``min_distance_m`` (float),
      ``cycle_p50_us`` / ``cycle_p99_us`` (float: the shield's cycle), ``loop_p99_us`` (float
      or None: the worker's whole step) and ``overruns`` (int or None: periods its loop
      missed), ``phase_lock`` (:class:`~sara_app.bus.messages.PhaseLockMsg` or None: the
      cycle phase's lock onto the skeletons, when on), ``robot_q_measured`` (list of float or
      None: where the controller reports the robot, rad), ``skeleton_age_ms`` (float, or dict
      human id to float), ``dropped`` (int, or dict reason to count), ``intervened`` (bool),
      ``speed_scale`` (PFL, float), ``jssa`` (dict: ``phi_m2``, ``active``, ``fallback``,
      ``reason``, ``link``, ``distance_m``, ``d_min_m``), ``tracking`` (dict human id to dict
      flag to count), ``tracking_now`` (dict human id to the present state:
      :mod:`sara_app.dashboard.tracking_text`), ``violations`` (list of dicts: ``human_id``,
      ``joint``, ``quantity``, ``value``, ``bound``), ``legs_below_m`` (dict human id to the
      height their unmeasured legs are held below, for people whose set bounds them);
      missing keys show as "n/a";
    - ``critical_pair (2, 3)`` or None: the JSSA critical pair (robot point, other point);
      ``critical_active``: whether JSSA modified the command this cycle;
    - ``links``: PFL energy and threshold per robot link (empty outside PFL);
    - ``contact_parts``: the body parts in possible contact, or None;
    - ``boxes``: environment boxes or None.
    """

    t_s: float
    q: np.ndarray
    humans: list[HumanDisplay] = field(default_factory=list)
    robot_ends: np.ndarray = field(default_factory=lambda: np.zeros((0, 0, 2, 3)))
    robot_radius: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))
    verified: bool = False
    contact_class: np.ndarray | None = None
    status: dict[str, Any] = field(default_factory=dict)
    critical_pair: np.ndarray | None = None
    critical_active: bool = False
    links: list[LinkEnergy] = field(default_factory=list)
    contact_parts: ContactParts | None = None
    boxes: EnvBoxes | None = None
