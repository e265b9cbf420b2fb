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

from sara_app.geometry.shapes import effective_volume_mc, point_segment_distance, union_volume_mc
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
    unavailable: int = 0
    """Future joint positions not checked: the model had no set for them (no velocity
    estimate at the measurement)."""
    unflagged: int | None = None
    """Of the misses, those at a measurement the conformance monitor had not faulted the person
    for (the residual risk: a live cell would have moved on them); None: not screened."""

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


Rates = dict[str, tuple[np.ndarray, np.ndarray]]
"""Per model that needs them, rates per frame and their error bounds: velocity estimates
``(T, J, 3)``, ``(T, J)`` (``acc``, ``combined``) or arm coordinate rates (``arm``)."""


def rates(reach: HumanReach, times_s: np.ndarray, y: np.ndarray, models: tuple[str, ...]) -> Rates:
    """The rates each model in ``models`` needs, estimated causally on the real time stamps
    with their error bounds (infinite where a frame has no usable past)."""
    p = reach.params
    out: Rates = {}
    if "acc" in models or "combined" in models:
        v = estimate_recording(times_s, y, p.delta_y_m, p.a_max_mps2)
        out["acc"] = out["combined"] = v
    if "arm" in models:
        idx = {j: i for i, j in enumerate(reach.skeleton.joints)}
        q, _ = arm_coordinates(y, idx)
        dq = coordinate_uncertainty(q, p.delta_y_m, frame_error(y, idx, p.delta_y_m))
        a = p.arm
        amax = np.array([a.angle_a_max_rad_s2, a.angle_a_max_rad_s2, a.r_a_max_mps2])
        out["arm"] = arm_velocities(times_s, q, dq, amax)
    return out


def occupancies(
    reach: HumanReach,
    times_s: np.ndarray,
    y: np.ndarray,
    t_start_s: np.ndarray,
    t_end_s: np.ndarray,
    models: tuple[str, ...] = MODELS,
    frames: np.ndarray | None = None,
    given: Rates | None = None,
) -> dict[str, Occupancy]:
    """Each model's capsules for every frame ``y (T, J, 3)`` (or only ``frames``) as a
    measurement, for intervals ``(K,)``: ``(F, K, C)``.

    Rates come from :func:`rates` (``given``: computed once by the caller). A model that needs
    a velocity estimate a frame does not have (the first frame; a joint whose estimate has no
    bound) is UNAVAILABLE there: its capsules that stand for such a joint get an infinite
    radius (never a capsule of made-up size). The combined model falls back on the speed
    model's ball, which needs no estimate; the arm model on its velocity sub-model.
    """
    rs = rates(reach, times_s, y, models) if given is None else given
    sel = np.arange(y.shape[0]) if frames is None else np.asarray(frames)
    ys = y[sel]
    out: dict[str, Occupancy] = {}
    for m in models:
        if m == "acc":
            v, dv = (a[sel] for a in rs[m])
            o = reach.acc(ys, v, np.where(np.isfinite(dv), dv, 0.0), t_start_s, t_end_s)
            cap, joint, _ = reach.coverage[m]
            missing = np.zeros((len(sel), len(o.names)), bool)
            np.logical_or.at(missing, (slice(None), cap), ~np.isfinite(dv[:, joint]))  # type: ignore[arg-type]
            radius = np.where(missing[:, None, :], np.inf, o.radius)
            o = Occupancy(m, o.ends, radius, o.names)
        elif m == "combined":
            v, dv = (a[sel] for a in rs[m])  # no estimate (infinite bound): the speed ball
            o = reach.combined(ys, np.nan_to_num(v), dv, t_start_s, t_end_s)
        elif m == "arm":
            qd, bound = (a[sel] for a in rs[m])
            bound = np.where(np.isfinite(bound), bound, 1e6)  # the rate sub-model is unused
            o = arm_occupancy(reach, ys, t_start_s, t_end_s, qd, bound)
        else:
            o = reach.model(m, ys, None, None, t_start_s, t_end_s)
        shape = (len(sel), len(t_end_s), len(o.names))
        out[m] = Occupancy(
            m, np.broadcast_to(o.ends, shape + (2, 3)), np.broadcast_to(o.radius, shape), o.names
        )
    return out


def _future(times_s: np.ndarray, horizon_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Future frame offsets: ``tau (T, K)`` = t_(i+k) - t_i on the real time stamps and
    ``valid (T, K)`` (a frame exists and lies within the horizon)."""
    T = len(times_s)
    K = max(1, int(np.max(np.searchsorted(times_s, times_s + horizon_s + 1e-12, "right")
                          - np.arange(T))) - 1)  # fmt: skip
    frame = np.arange(T)[:, None] + np.arange(1, K + 1)[None, :]
    tau = times_s[np.minimum(frame, T - 1)] - times_s[:, None]
    valid = (frame < T) & (tau <= horizon_s + 1e-12)
    return np.where(valid, tau, np.nan), valid


def containment(
    reach: HumanReach,
    times_s: np.ndarray,
    y: np.ndarray,
    horizon_s: float,
    models: tuple[str, ...] = MODELS,
    n_worst: int = 5,
    faulted: np.ndarray | None = None,
    effective_of: tuple[str, ...] | None = None,
) -> dict[str, Containment]:
    """Share of future joint positions inside each model's set, per model (see module doc), and
    inside the effective set (key :data:`EFFECTIVE`): what the verdict relies on. A body part
    is cleared when ANY model's set for it is free, so a future position is inside the
    effective set only when it is inside EVERY model in use that has a set for it (a model
    without one, unavailable there, clears nothing). ``faulted (T,)``: the frames at which the
    conformance monitor faulted the person (:attr:`Screening.faulted
    <sara_app.human.intake.Screening.faulted>`); the effective set's misses at the others are
    counted as ``unflagged``. ``effective_of``: the models in use in the cell (default
    ``models``).

    Every frame pair is evaluated at its own time difference, so jittered time stamps (a 60 Hz
    tracker stamped in milliseconds) are analysed as they are. A (frame, joint) the model is
    unavailable for (:func:`occupancies`) is counted as ``unavailable``, not checked.
    The recording is ground truth with zero latency: the models run with delay 0 here, so
    a measured miss is a miss of the motion model itself, not hidden by the delay's slack.
    """
    reach = HumanReach(replace(reach.params, delay_s=0.0))
    T = y.shape[0]
    tau, valid = _future(times_s, horizon_s)
    K = tau.shape[1]
    occ = _occupancies_at(reach, times_s, y, tau, models)
    names = reach.skeleton.joints
    frame = np.minimum(np.arange(T)[:, None] + np.arange(1, K + 1)[None, :], T - 1)
    fut = y[frame]  # (T, K, J, 3)
    results: dict[str, Containment] = {}
    J = len(names)
    eff_inside = np.ones((T, K, J), dtype=bool)
    eff_worst = np.full((T, K, J), -np.inf)
    for m in models:
        o = occ[m]
        cap, joint, margin = reach.coverage[m]
        d = point_segment_distance(fut[:, :, joint], o.ends[:, :, cap])  # (T, K, M)
        excess = d + margin - o.radius[:, :, cap]
        # A joint is contained when every capsule that must hold it does.
        inside = np.ones((T, K, J), dtype=bool)
        np.logical_and.at(inside, (slice(None), slice(None), joint), excess <= 1e-12)  # type: ignore[arg-type]
        worst_excess = np.full((T, K, J), -np.inf)
        np.maximum.at(worst_excess, (slice(None), slice(None), joint), excess)  # type: ignore[arg-type]
        known = np.ones((T, K, J), dtype=bool)
        np.logical_and.at(known, (slice(None), slice(None), joint),  # type: ignore[arg-type]
                          np.isfinite(o.radius[:, :, cap]))  # fmt: skip
        v3 = valid[:, :, None] & known
        results[m] = _tally(m, inside, worst_excess, v3, names, times_s, tau, n_worst)
        results[m].unavailable = int((valid[:, :, None] & ~known).sum())
        if effective_of is None or m in effective_of:
            eff_inside &= inside | ~known
            eff_worst = np.maximum(eff_worst, np.where(known, worst_excess, -np.inf))
    v3 = np.broadcast_to(valid[:, :, None], (T, K, J))
    eff = _tally(EFFECTIVE, eff_inside, eff_worst, v3, names, times_s, tau, n_worst)
    if faulted is not None:
        eff.unflagged = int((~eff_inside & v3 & ~np.asarray(faulted, bool)[:, None, None]).sum())
    results[EFFECTIVE] = eff
    return results


def _tally(
    model: str,
    inside: np.ndarray,
    worst_excess: np.ndarray,
    v3: np.ndarray,
    names: tuple[str, ...],
    times_s: np.ndarray,
    tau: np.ndarray,
    n_worst: int,
) -> Containment:
    """A :class:`Containment` from ``inside``, ``worst_excess`` and the checked ``v3`` (all
    ``(T, K, J)``): counts, misses per joint and the ``n_worst`` escapes."""
    res = Containment(model, int(v3.sum()), int((inside & v3).sum()))
    miss = ~inside & v3
    for j in np.unique(np.nonzero(miss)[2]):
        res.misses_per_joint[names[j]] = int(miss[:, :, j].sum())
    # an excess that overflowed (coordinates near the float limit) is a miss by more than any
    # finite one: listed first, never dropped from the list as not finite
    flat = np.where(miss, np.nan_to_num(worst_excess, nan=np.inf, posinf=np.inf), -np.inf)
    for f in np.argsort(flat, axis=None)[::-1][:n_worst]:
        i, k, j = np.unravel_index(f, flat.shape)
        if flat[i, k, j] == -np.inf:
            break
        res.worst.append(
            Miss(names[j], int(i), float(times_s[i]), float(tau[i, k]), float(flat[i, k, j]))
        )
    return res


def _occupancies_at(
    reach: HumanReach,
    times_s: np.ndarray,
    y: np.ndarray,
    tau: np.ndarray,
    models: tuple[str, ...],
) -> dict[str, Occupancy]:
    """Each model's sets at the instants ``tau (T, K)`` after each frame (nan: unused):
    ``(T, K, C)``. One call when every frame has the same offsets (uniform sampling), else
    one per frame."""
    filled = np.where(np.isfinite(tau), tau, np.nanmax(tau, initial=0.0))
    first = filled[0]
    if np.allclose(filled[np.isfinite(tau).all(axis=1)], first, rtol=0, atol=1e-12):
        return occupancies(reach, times_s, y, first, first, models)
    rs = rates(reach, times_s, y, models)
    ends: dict[str, list[np.ndarray]] = {m: [] for m in models}
    radius: dict[str, list[np.ndarray]] = {m: [] for m in models}
    names: dict[str, tuple[str, ...]] = {}
    for i in range(y.shape[0]):
        row = occupancies(reach, times_s, y, filled[i], filled[i], models, np.array([i]), rs)
        for m in models:  # copies: the kernels' outputs are buffers reused by the next call
            ends[m].append(np.array(row[m].ends))
            radius[m].append(np.array(row[m].radius))
            names[m] = row[m].names
    return {m: Occupancy(m, np.concatenate(ends[m]), np.concatenate(radius[m]), names[m])
            for m in models}  # fmt: skip


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
    (:func:`~sara_app.geometry.shapes.effective_volume_mc`)."""
    rng = np.random.default_rng(seed)
    frames = np.linspace(1, y.shape[0] - 1, min(n_frames, y.shape[0] - 1)).astype(int)
    t = np.array([horizon_s])
    occ = occupancies(reach, times_s, y, np.zeros(1), t, models)
    out = {}
    known = {m: np.isfinite(occ[m].radius[frames, 0]).all(axis=-1) for m in models}
    for m in models:  # frames where a model is unavailable (no velocity estimate) are left out
        o = occ[m]
        vols = [union_volume_mc(o.ends[f, 0], o.radius[f, 0], n_samples, rng)[0]
                for f, ok in zip(frames, known[m]) if ok]  # fmt: skip
        out[m] = float(np.mean(vols)) if vols else float("nan")
    frames = frames[np.all([known[m] for m in models], axis=0)]
    if len(models) > 1 and len(frames):
        maps = [part_capsules(reach, m) for m in models]
        vols = [
            effective_volume_mc(
                [(occ[m].ends[f, 0], occ[m].radius[f, 0]) for m in models], maps, n_samples, rng
            )[0]
            for f in frames
        ]
        out[EFFECTIVE] = float(np.mean(vols))
    return out
