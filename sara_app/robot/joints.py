"""Joint states, checked joint-limit arrays and waypoint checks shared by paths, followers and
failsafe stops; the tolerances they share."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sara_app.errors import RobotModelError
from sara_app.robot.model import JointLimits

__all__ = [
    "LIMIT_MARGIN",
    "REST_A",
    "REST_V",
    "S_TOL",
    "JointState",
    "check_waypoints",
    "limit_arrays",
]

LIMIT_MARGIN = 1e-9
"""Relative margin taken off every path-speed box so rounding can never cross a joint limit."""

S_TOL = 1e-9
"""rad: path positions closer than this are the same point."""
REST_V = 1e-9
"""rad/s: path speed below which (with :data:`REST_A`, rad/s^2) the robot counts as standing."""
REST_A = 1e-7


@dataclass(frozen=True)
class JointState:
    """Joint position (rad), velocity (rad/s) and acceleration (rad/s^2), arrays ``(n,)``."""

    q: np.ndarray
    v: np.ndarray
    a: np.ndarray


class LimitArrays:
    """Float copies of a :class:`JointLimits` checked against a joint count."""

    __slots__ = ("source", "q_min", "q_max", "v", "a", "j")

    def __init__(self, limits: JointLimits, n: int) -> None:
        self.source = limits
        arrays = []
        for name in ("q_min", "q_max", "v_max", "a_max", "j_max"):
            arr = np.asarray(getattr(limits, name), dtype=float)
            if arr.shape != (n,):
                raise RobotModelError(
                    f"joint limit {name} has shape {arr.shape}; expected ({n},) for {n} joints"
                )
            if not np.all(np.isfinite(arr)):
                raise RobotModelError(f"joint limit {name} = {arr.tolist()} is not finite")
            arrays.append(arr)
        self.q_min, self.q_max, self.v, self.a, self.j = arrays
        for name, arr in (("v_max", self.v), ("a_max", self.a), ("j_max", self.j)):
            if np.any(arr <= 0):
                i = int(np.flatnonzero(arr <= 0)[0])
                raise RobotModelError(f"joint {i}: {name} = {arr[i]}; expected a positive value")


def limit_arrays(limits: JointLimits, n: int) -> LimitArrays:
    """Checked float arrays of ``limits`` for ``n`` joints."""
    if not isinstance(limits, JointLimits):
        raise RobotModelError(
            f"limits is a {type(limits).__name__}; expected sara_app.robot.model.JointLimits"
        )
    return LimitArrays(limits, n)


def check_waypoints(waypoints: object, limits: JointLimits | None = None, n: int | None = None):
    """Waypoints as a float array ``(W, n)``; raise :class:`RobotModelError` naming the problem.

    Checks the shape, finiteness and, with ``limits``, the joint position box; errors name the
    waypoint index and the joint index.
    """
    if limits is not None and not isinstance(limits, JointLimits):
        raise RobotModelError(
            f"limits is a {type(limits).__name__}; expected sara_app.robot.model.JointLimits"
        )
    try:
        wps = np.array(waypoints, dtype=float)
    except (TypeError, ValueError) as exc:
        raise RobotModelError(f"waypoints cannot be read as a float array: {exc}") from None
    if n is None and limits is not None:
        n = int(np.shape(limits.q_min)[0])
    if wps.ndim != 2 or wps.shape[0] < 1 or wps.shape[1] < 1:
        want = f"(W, {n})" if n is not None else "(W, n)"
        raise RobotModelError(f"waypoints have shape {wps.shape}; expected {want} with W >= 1")
    if n is not None and wps.shape[1] != n:
        raise RobotModelError(
            f"waypoints have {wps.shape[1]} joints (shape {wps.shape}); expected {n}"
        )
    bad = ~np.isfinite(wps)
    if bad.any():
        i, j = (int(x) for x in np.argwhere(bad)[0])
        raise RobotModelError(
            f"waypoint {i} joint {j} is {wps[i, j]}; expected a finite joint position"
        )
    if limits is not None:
        lo = np.asarray(limits.q_min, dtype=float)
        hi = np.asarray(limits.q_max, dtype=float)
        out = (wps < lo) | (wps > hi)
        if out.any():
            i, j = (int(x) for x in np.argwhere(out)[0])
            raise RobotModelError(
                f"waypoint {i} joint {j} = {wps[i, j]:.6g} rad is outside the joint range "
                f"[{lo[j]:.6g}, {hi[j]:.6g}] rad: goal unreachable"
            )
    return wps
