"""The shielded trajectory (Pereira & Althoff 2016 Sec. II, Thumm et al. 2024 Sec. III-B): one
intended control step of the path follower followed by the failsafe stop from its end, sampled for
verification: sample times, path and joint states, and rigorous per-interval bounds on joint speed
and acceleration (:func:`sara_app.robot.failsafe.interval_bounds`), from one compiled pass
(:mod:`sara_app.robot.trajectory_kernels`; its numpy reference is in ``tests/``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sara_app.errors import RobotModelError
from sara_app.robot.failsafe import BOUND_PAD, StopProfile
from sara_app.robot.path import PathTrajectory
from sara_app.robot.trajectory import FollowerStep, PathFollower
from sara_app.robot.trajectory_kernels import shielded_samples_kernel

__all__ = ["ShieldedTrajectory", "from_samples", "shielded_trajectory"]

_Samples = tuple[
    np.ndarray, tuple[np.ndarray, ...], np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
    np.ndarray, np.ndarray,
]  # fmt: skip


def _samples(path: PathTrajectory, step: FollowerStep, m: int) -> _Samples:
    """Samples of ``step`` + its failsafe in ``m`` intervals, compiled: ``(times, (s, s', s''),
    q, dq/ds, v, a, v_bound, a_bound, sd_max)``."""
    head, stop = step.profile, step.stop.profile
    s0, v0, a0 = head.start
    K = m + 1
    n = path.n_joints
    times = np.empty(K + 1)
    ps = np.empty((3, K + 1))
    joint = np.empty((5, K + 1, n))
    bounds = np.empty((2, K, n))
    sd_max = np.empty(K)
    phases = np.array(head.durs + stop.durs + head.jerks + stop.jerks)  # durations, jerks
    p_s0, p_len, poly, M1, M2, qs = path._piece_tables  # a one-point path: one piece of length 0
    shielded_samples_kernel(
        step.dt, stop.duration, s0, v0, a0, phases, p_s0, p_len, poly, M1, M2, qs, BOUND_PAD,
        times, ps, joint, bounds, sd_max,
    )  # fmt: skip
    s, sd, sdd = ps
    return times, (s, sd, sdd), joint[0], joint[1], joint[3], joint[4], bounds[0], bounds[1], sd_max


@dataclass(frozen=True)
class ShieldedTrajectory:
    """One intended control step followed by the failsafe stop from its end.

    ``times`` ``(K+1,)`` (s, from the current state); ``q``, ``v``, ``a`` ``(K+1, n)`` there;
    ``s``, ``sd``, ``sdd`` the path state there; samples ``0..failsafe_index`` are the intended
    step, ``failsafe_index..K`` the failsafe. ``v_bound``, ``a_bound`` ``(K, n)``: rigorous
    bounds on ``|v_j(t)|`` and ``|a_j(t)|`` over each ``[times[k], times[k+1]]``.
    ``dq`` ``(K+1, n)``: the path tangent ``dq/ds`` at the samples (``v = dq s'``);
    ``sd_max`` ``(K,)``: the exact largest path speed ``s'`` over each interval.
    ``step``: the follower step to commit if this trajectory is verified
    (``follower.commit(traj.step)``); ``stop``: the failsafe from the end of the step.
    """

    times: np.ndarray
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    s: np.ndarray
    sd: np.ndarray
    sdd: np.ndarray
    failsafe_index: int
    v_bound: np.ndarray
    a_bound: np.ndarray
    dq: np.ndarray
    sd_max: np.ndarray
    step: FollowerStep

    @property
    def stop(self) -> StopProfile:
        """The failsafe from the end of the step (the step's, made when first read)."""
        return self.step.stop

    @property
    def duration_s(self) -> float:
        return float(self.times[-1])


def shielded_trajectory(
    follower: PathFollower,
    dt: float,
    n_intervals: int | None = None,
    *,
    max_interval_s: float = 0.01,
) -> ShieldedTrajectory:
    """The follower's next step of ``dt`` seconds (follower unchanged) + the failsafe after it.

    The failsafe part is split into ``n_intervals`` equal intervals (default: as few as keep
    every interval at most ``max_interval_s`` long; none if the robot is at rest after the
    step). The intended step is always one interval.
    """
    step = follower.peek(dt)
    stop = step.stop
    T = stop.duration_s
    if n_intervals is None:
        if not (math.isfinite(max_interval_s) and max_interval_s > 0):
            raise RobotModelError(f"max_interval_s = {max_interval_s!r}; expected a time > 0")
        m = max(1, math.ceil(T / max_interval_s - 1e-9)) if T > 0 else 0
    else:
        if not isinstance(n_intervals, int) or n_intervals < 1:
            raise RobotModelError(f"n_intervals = {n_intervals!r}; expected an integer >= 1")
        m = n_intervals if T > 0 else 0
    return from_samples(step, _samples(follower.path, step, m))


def from_samples(step: FollowerStep, samples: _Samples) -> ShieldedTrajectory:
    """The trajectory of ``step`` + its failsafe from its samples ``(times, (s, s', s''), q,
    dq/ds, v, a, v_bound, a_bound, sd_max)`` (kept, not copied)."""
    times, (s, sd, sdd), q, dq, v, a, v_bound, a_bound, sd_max = samples
    # ShieldedTrajectory(...) with the fields set at once instead of one frozen-dataclass
    # __setattr__ each (the same object, a third of the cost)
    traj = object.__new__(ShieldedTrajectory)
    traj.__dict__.update(
        times=times, q=q, v=v, a=a, s=s, sd=sd, sdd=sdd, failsafe_index=1, v_bound=v_bound,
        a_bound=a_bound, dq=dq, sd_max=sd_max, step=step,
    )  # fmt: skip
    return traj
