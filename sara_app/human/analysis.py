"""Containment and tightness of the reachability models on recorded or synthetic motion.

Containment: every frame i is taken as a measurement; for every later frame j within the horizon,
each model's set for the instant tau = t_j - t_i (the tightest set the model gives for that
time) must contain every joint of frame j, grown by its body part's half thickness. Frames are
batched as "humans" and the future offsets as intervals, so one vectorised call per model covers
the whole recording.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from sara_app.errors import InputError
from sara_app.geometry import effective_volume_mc, point_segment_distance, union_volume_mc
from sara_app.human.arm import (
    arm_coordinates,
    arm_occupancy,
    coordinate_uncertainty,
    frame_error,
)
from sara_app.human.reach import MODELS, HumanReach, Occupancy, part_capsules
from sara_app.human.velocity import estimate_recording


@dataclass
class Miss:
    """The worst escape of one joint from one model's set."""

    joint: str
    frame: int
    t_s: float
    dt_s: float
    excess_m: float


@dataclass
class Containment:
    model: str
    checked: int
    contained: int
    misses_per_joint: dict[str, int] = field(default_factory=dict)
    worst: list[Miss] = field(default_factory=list)

    @property
    def share(self) -> float:
        return self.contained / self.checked if self.checked else float("nan")


EFFECTIVE = "effective"
"""The key of the per-body-part intersection in :func:`mean_volume`."""


def arm_velocities(
    times_s: np.ndarray, q: np.ndarray, dq: np.ndarray, amax: np.ndarray, max_lag: int = 8
) -> tuple[np.ndarray, np.ndarray]:
    """Causal backward-difference rates of the arm coordinates ``q (T, 2, 3)`` with error bound
    (dq_i + dq_{i-l}) / h + a_max h / 2; phi differences are wrapped to (-pi, pi]."""
    T = q.shape[0]
    qd = np.zeros_like(q)
    bound = np.full_like(q, np.inf)
    for i in range(1, T):
        best = np.full(q.shape[1:], np.inf)
        for lag in range(1, min(max_lag, i) + 1):
            h = times_s[i] - times_s[i - lag]
            diff = q[i] - q[i - lag]
            diff[:, 0] = (diff[:, 0] + np.pi) % (2 * np.pi) - np.pi
            b = (dq[i] + dq[i - lag]) / h + 0.5 * amax * h
            better = b < best
            best = np.where(better, b, best)
            qd[i] = np.where(better, diff / h, qd[i])
        bound[i] = best
    return qd, bound


def occupancies(
    reach: HumanReach,
    times_s: np.ndarray,
    y: np.ndarray,
    t_start_s: np.ndarray,
    t_end_s: np.ndarray,
    models: tuple[str, ...] = MODELS,
) -> dict[str, Occupancy]:
    """Each model's capsules for every frame ``y (T, J, 3)`` as a measurement.

    Velocities (for acc, and for the arm model's acceleration sub-model) are estimated causally
    with their error bounds; frames without a past have an infinite bound.
    """
    p = reach.params
    out: dict[str, Occupancy] = {}
    velocities: tuple[np.ndarray, np.ndarray] | None = None
    for m in models:
        if m in ("acc", "combined") and velocities is None:
            velocities = estimate_recording(times_s, y, p.delta_y_m, p.a_max_mps2)
        if m == "acc" and velocities is not None:
            v, dv = velocities
            out[m] = reach.acc(y, v, np.where(np.isfinite(dv), dv, 1e6), t_start_s, t_end_s)
        elif m == "combined" and velocities is not None:
            v, dv = velocities  # no estimate yet (infinite bound): the speed model's ball
            out[m] = reach.combined(y, np.nan_to_num(v), dv, t_start_s, t_end_s)
        elif m == "arm":
            idx = {j: i for i, j in enumerate(reach.skeleton.joints)}
            q, _ = arm_coordinates(y, idx)
            dq = coordinate_uncertainty(q, p.delta_y_m, frame_error(y, idx, p.delta_y_m))
            a = p.arm
            amax = np.array([a.angle_a_max_rad_s2, a.angle_a_max_rad_s2, a.r_a_max_mps2])
            qd, bound = arm_velocities(times_s, q, dq, amax)
            bound = np.where(np.isfinite(bound), bound, 1e6)
            out[m] = arm_occupancy(reach, y, t_start_s, t_end_s, qd, bound)
        else:
            out[m] = reach.model(m, y, None, None, t_start_s, t_end_s)
        o, shape = out[m], (y.shape[0], len(t_end_s), len(out[m].names))
        out[m] = Occupancy(
            m, np.broadcast_to(o.ends, shape + (2, 3)), np.broadcast_to(o.radius, shape), o.names
        )
    return out


def containment(
    reach: HumanReach,
    times_s: np.ndarray,
    y: np.ndarray,
    horizon_s: float,
    models: tuple[str, ...] = MODELS,
    n_worst: int = 5,
) -> dict[str, Containment]:
    """Share of future joint positions inside each model's set, per model (see module doc).

    The recording is ground truth with zero latency: the models run with delay 0 here, so
    a measured miss is a miss of the motion model itself, not hidden by the delay's slack.
    """
    reach = HumanReach(replace(reach.params, delay_s=0.0))
    dt = float(np.median(np.diff(times_s)))
    n_off = max(1, int(np.floor(horizon_s / dt + 1e-9)))
    offsets = np.arange(1, n_off + 1)
    T = y.shape[0]
    # Future frames are indexed by offset, so every frame must be one period apart.
    if not np.allclose(np.diff(times_s), dt, rtol=1e-6, atol=1e-9):
        raise InputError(
            f"containment needs a uniformly sampled recording; frame periods range from "
            f"{np.diff(times_s).min():.6f} to {np.diff(times_s).max():.6f} s: resample it first"
        )
    taus = offsets * dt
    results: dict[str, Containment] = {}
    occ = occupancies(reach, times_s, y, taus, taus, models)
    names = reach.skeleton.joints
    for m in models:
        o = occ[m]
        cap, joint, margin = reach.coverage[m]
        frame = np.arange(T)[:, None] + offsets[None, :]  # (T, K) future frame index
        valid = frame < T
        fut = y[np.minimum(frame, T - 1)]  # (T, K, J, 3)
        d = point_segment_distance(fut[:, :, joint], o.ends[:, :, cap])  # (T, K, M)
        excess = d + margin - o.radius[:, :, cap]
        inside_entry = excess <= 1e-12
        # A joint is contained when every capsule that must hold it does.
        J = len(names)
        inside = np.ones((T, len(offsets), J), dtype=bool)
        np.logical_and.at(inside, (slice(None), slice(None), joint), inside_entry)  # type: ignore[arg-type]
        worst_excess = np.full((T, len(offsets), J), -np.inf)
        np.maximum.at(worst_excess, (slice(None), slice(None), joint), excess)  # type: ignore[arg-type]
        if m == "acc":  # frame 0 has no velocity estimate: the model is not available there
            valid = valid & (np.arange(T)[:, None] > 0)
        v3 = np.broadcast_to(valid[:, :, None], inside.shape)
        res = Containment(m, int(v3.sum()), int((inside & v3).sum()))
        miss = ~inside & v3
        for j in np.unique(np.nonzero(miss)[2]):
            res.misses_per_joint[names[j]] = int(miss[:, :, j].sum())
        flat = np.where(miss, worst_excess, -np.inf)
        order = np.argsort(flat, axis=None)[::-1][:n_worst]
        for f in order:
            i, k, j = np.unravel_index(f, flat.shape)
            if not np.isfinite(flat[i, k, j]):
                break
            res.worst.append(
                Miss(names[j], int(i), float(times_s[i]), float(taus[k]), float(flat[i, k, j]))
            )
        results[m] = res
    return results


def mean_volume(
    reach: HumanReach,
    times_s: np.ndarray,
    y: np.ndarray,
    horizon_s: float,
    models: tuple[str, ...] = MODELS,
    n_frames: int = 20,
    n_samples: int = 20_000,
    seed: int = 0,
) -> dict[str, float]:
    """Mean Monte-Carlo volume (m^3) of each model's set over [0, horizon] on ``n_frames``
    evenly spaced frames; with several models also ``"effective"``: the per-body-part
    intersection of their sets, what the per-part verdict uses
    (:func:`~sara_app.geometry.effective_volume_mc`)."""
    rng = np.random.default_rng(seed)
    frames = np.linspace(1, y.shape[0] - 1, min(n_frames, y.shape[0] - 1)).astype(int)
    t = np.array([horizon_s])
    occ = occupancies(reach, times_s, y, np.zeros(1), t, models)
    out = {}
    for m in models:
        o = occ[m]
        vols = [union_volume_mc(o.ends[f, 0], o.radius[f, 0], n_samples, rng)[0] for f in frames]
        out[m] = float(np.mean(vols))
    if len(models) > 1:
        maps = [part_capsules(reach, m) for m in models]
        vols = [
            effective_volume_mc(
                [(occ[m].ends[f, 0], occ[m].radius[f, 0]) for m in models], maps, n_samples, rng
            )[0]
            for f in frames
        ]
        out[EFFECTIVE] = float(np.mean(vols))
    return out
