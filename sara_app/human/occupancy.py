"""One reachability model's capsules for a batch of people and intervals (the output of every
model in :mod:`sara_app.human.reach` and :mod:`sara_app.human.arm`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Occupancy:
    """Capsules of one model: ``ends (H, K, C, 2, 3)``, ``radius (H, K, C)``, names ``(C,)``.

    From the buffered model methods, axes of length 1 broadcast (a model whose capsule ends do
    not move has ``ends (H, 1, C, 2, 3)``; one whose radius is the same for every human has
    ``radius (1, K, C)``).
    """

    model: str
    ends: np.ndarray
    radius: np.ndarray
    names: tuple[str, ...]
