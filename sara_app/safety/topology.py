"""Topology declarations of the PFL check, keyed by name (Thumm et al. 2024 eq. 36-37 and eq. 39).

- :data:`ROBOT_UNCLAMPABLE_PAIRS`: per robot, the link pairs that cannot clamp a body part
  between them (the set G^(r) of eq. 36). These are design declarations, to be confirmed by the
  safety engineer for the actual robot and tool. Declared here: pairs of links joined by one
  joint whose gap the manufacturer keeps finger-safe. NOT declared (so they can clamp): the
  Panda's elbow pinch between ``panda_link3`` and ``panda_link5`` and the UR5e's elbow between
  ``upper_arm_link`` and ``forearm_link`` (both fold far enough to trap a hand or forearm); the
  UR10e's as the UR5e's. Any other robot declares none unless its scenario does.
- :data:`HUMAN_SAFE_PAIRS`: body-part pairs that cannot be clamped together as one stack (G^(h)
  of eq. 39): parts of the same extremity and parts joined by a joint (they always touch, and
  pressing a limb against its own neighbour is not a clamping against a fixed object).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from sara_app.errors import UnknownNameError

ROBOT_UNCLAMPABLE_PAIRS: dict[str, tuple[tuple[str, str], ...]] = {
    "panda": (
        ("panda_link0", "panda_link1"),
        ("panda_link1", "panda_link2"),
        ("panda_link2", "panda_link3"),
        ("panda_link3", "panda_link4"),
        ("panda_link4", "panda_link5"),
        ("panda_link5", "panda_link6"),
        ("panda_link6", "panda_link7"),
        ("panda_link7", "panda_hand"),  # rigidly attached (fixed joint)
    ),
    "ur5e": (
        ("base_link", "shoulder_link"),
        ("shoulder_link", "upper_arm_link"),
        ("forearm_link", "wrist_1_link"),
        ("wrist_1_link", "wrist_2_link"),
        ("wrist_2_link", "wrist_3_link"),
    ),
}
ROBOT_UNCLAMPABLE_PAIRS["ur10e"] = ROBOT_UNCLAMPABLE_PAIRS["ur5e"]  # the same links and joints

_LIMBS = (
    ("l_upper_arm", "l_lower_arm", "l_hand"),
    ("r_upper_arm", "r_lower_arm", "r_hand"),
    ("l_thigh", "l_shin", "l_foot"),
    ("r_thigh", "r_shin", "r_foot"),
)
HUMAN_SAFE_PAIRS: tuple[tuple[str, str], ...] = tuple(
    (a, b) for limb in _LIMBS for i, a in enumerate(limb) for b in limb[i + 1 :]
) + (
    ("head", "torso"),
    ("torso", "l_upper_arm"),
    ("torso", "r_upper_arm"),
    ("torso", "l_thigh"),
    ("torso", "r_thigh"),
)


def unclampable_matrix(
    robot: str, link_names: Sequence[str], pairs: Sequence[tuple[str, str]] | None = None
) -> np.ndarray:
    """``(L, L)`` bool, symmetric: link pair ``(i, l)`` is in G^(r). ``pairs`` overrides the
    declaration of ``robot``; an unknown link name raises. A robot without a declaration (a
    URDF of your own, without the scenario's ``shield.pfl.unclampable_pairs``) declares no
    pair: CONSERVATIVE, every link pair is taken to be able to clamp a body part."""
    if pairs is None:
        pairs = ROBOT_UNCLAMPABLE_PAIRS.get(robot, ())
    names = list(link_names)
    out = np.zeros((len(names), len(names)), dtype=bool)
    for a, b in pairs:
        for n in (a, b):
            if n not in names:
                raise UnknownNameError(f"link of {robot!r}", n, names)
        i, j = names.index(a), names.index(b)
        out[i, j] = out[j, i] = True
    return out


def human_safe_matrix(
    part_names: Sequence[str],
    human_index: Sequence[int] | np.ndarray | None = None,
    pairs: Sequence[tuple[str, str]] = HUMAN_SAFE_PAIRS,
) -> np.ndarray:
    """``(P, P)`` bool, symmetric: parts ``j, j'`` of the SAME human form a pair in ``pairs``.

    ``part_names (P,)`` may repeat names for several humans; ``human_index (P,)`` says which
    human each part belongs to (default: all one human).
    """
    P = len(part_names)
    owner = np.zeros(P, dtype=int) if human_index is None else np.asarray(human_index)
    known = {n for pair in pairs for n in pair}
    safe = {frozenset(p) for p in pairs}
    out = np.zeros((P, P), dtype=bool)
    for j, a in enumerate(part_names):
        if a not in known:
            raise UnknownNameError("body part", a, sorted(known))
        for jj in range(j + 1, P):
            if owner[j] == owner[jj] and frozenset((a, part_names[jj])) in safe:
                out[j, jj] = out[jj, j] = True
    return out
