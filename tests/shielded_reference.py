"""The shielded trajectory's samples composed of the profile's and the path's numpy methods: the
reference of the compiled sampling (``trajectory_kernels.shielded_samples_kernel``, run by
:func:`~sara_app.robot.shielded.shielded_trajectory`)."""

from __future__ import annotations

import math

import numpy as np

from sara_app.robot.failsafe import interval_bounds
from sara_app.robot.shielded import ShieldedTrajectory, from_samples
from sara_app.robot.trajectory import PathFollower


def shielded_reference(
    follower: PathFollower,
    dt: float,
    n_intervals: int | None = None,
    *,
    max_interval_s: float = 0.01,
) -> ShieldedTrajectory:
    """:func:`~sara_app.robot.shielded.shielded_trajectory` with numpy sampling (the same
    sample grid: one interval for the step, the stop in ``n_intervals`` equal ones)."""
    step = follower.peek(dt)
    T = step.stop.duration_s
    if n_intervals is None:
        m = max(1, math.ceil(T / max_interval_s - 1e-9)) if T > 0 else 0
    else:
        m = n_intervals if T > 0 else 0
    path = follower.path
    times = np.empty(m + 2)
    times[0], times[1] = 0.0, step.dt
    times[2:] = step.dt + T * (np.arange(1, m + 1) / max(m, 1))
    prof = step.profile.then(step.stop.profile)
    s, sd, sdd = prof.evaluate(times)
    q, dq, d2q = path._derivatives_array(s, 2)
    v = dq * sd[:, None]
    a = d2q * (sd * sd)[:, None] + dq * sdd[:, None]
    v_bound, a_bound = interval_bounds(path, prof, times, s, sd, sdd, dq)
    sd_max = prof.interval_maxima(times, sd, sdd)[0]
    return from_samples(step, (times, (s, sd, sdd), q, dq, v, a, v_bound, a_bound, sd_max))
