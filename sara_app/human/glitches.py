"""Scripted tracking glitches for simulated sensors: what real trackers do to a skeleton.

- ``swap``: the joint reports another joint's position (a marker or label swap);
- ``freeze``: the joint repeats the value it had when the glitch began (a frozen marker);
- ``spike``: the joint is offset by ``offset_m`` (one-frame spikes: a short ``duration_s``).

Each glitch is active on ``[start_s, start_s + duration_s)`` of the scenario's time. Used by the
simulation and the live replayer, after the sensor noise, so the cell sees what a tracker
would send.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol

import numpy as np

from sara_app.human.skeleton import FULL_JOINTS


class GlitchLike(Protocol):
    @property
    def kind(self) -> str: ...
    @property
    def joint(self) -> str: ...
    @property
    def other(self) -> str: ...
    @property
    def start_s(self) -> float: ...
    @property
    def duration_s(self) -> float: ...
    @property
    def offset_m(self) -> tuple[float, float, float]: ...


class Glitches:
    """The glitches of one sensor, with the values frozen ones hold."""

    def __init__(self, specs: Sequence[GlitchLike]) -> None:
        self.specs = list(specs)
        self.frozen: dict[int, np.ndarray] = {}

    def apply(self, t_s: float, y: np.ndarray) -> np.ndarray:
        """``y (J, 3)`` as the glitching tracker reports it at scenario time ``t_s``."""
        if not self.specs:
            return y
        out = y.copy()
        for k, g in enumerate(self.specs):
            if not g.start_s <= t_s < g.start_s + g.duration_s:
                self.frozen.pop(k, None)
                continue
            j = FULL_JOINTS.index(g.joint)
            if g.kind == "swap":
                out[j] = y[FULL_JOINTS.index(g.other)]
            elif g.kind == "freeze":
                out[j] = self.frozen.setdefault(k, y[j].copy())
            else:
                out[j] = y[j] + np.asarray(g.offset_m)
        return out
