"""Containment and tightness of the reachability models on recorded or synthetic motion.

Containment: every frame i is taken as a measurement; for every later frame j within the horizon,
each model's set for the instant tau = t_j - t_i (the tightest set the model gives for that
time) must contain every joint of frame j, grown by its body part's half thickness. Frames are
batched as "humans" and the future offsets as intervals, so one vectorised call per model covers
a chunk of frames (:data:`PAIRS_PER_CHUNK` frame pairs: memory bounded whatever the recording).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np

from sara_app.geometry.shapes import effective_volume_mc, union_volume_mc
from sara_app.human.arm import (
    arm_coordinates,
    arm_occupancy,
    coordinate_uncertainty,
    frame_error,
)
from sara_app.human.containment_kernels import cover_joints
from sara_app.human.reach import MODELS, HumanReach, Occupancy, part_capsules
from sara_app.human.velocity import estimate_recording
from sara_app.kernel_types import as_f8


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


PAIRS_PER_CHUNK = 20_000
"""Frame pairs (a measurement and one future frame) analysed at once. Every model's sets, the
distances and the tallies take about 12 kB per pair, so a chunk holds about 250 MB whatever the
recording's length and rate: the whole of CMU 62_11 (30 s at 120 Hz) at a 0.5 s horizon took
2.6 GB in one piece, and a minute at 1 kHz would have taken about 360 GB."""


def _horizon_frames(times_s: np.ndarray, horizon_s: float) -> int:
    """``K``: the most future frames any frame has within the horizon (at least 1)."""
    T = len(times_s)
    ahead = np.searchsorted(times_s, times_s + horizon_s + 1e-12, "right") - np.arange(T)
    return max(1, int(np.max(ahead)) - 1)


def _future_frames(
    times_s: np.ndarray, horizon_s: float, K: int, rows: slice
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For the frames ``rows`` (``F`` of them): the future frames ``frame (F, K)`` (clipped to
    the last), their offsets ``tau (F, K)`` = t_(i+k) - t_i on the real time stamps (nan where
    invalid) and ``valid (F, K)`` (a frame exists and lies within the horizon; a prefix of
    each row, as both conditions grow with k)."""
    T = len(times_s)
    ahead = np.arange(T)[rows][:, None] + np.arange(1, K + 1)[None, :]
    frame = np.minimum(ahead, T - 1)
    tau = times_s[frame] - times_s[rows][:, None]
    valid = (ahead < T) & (tau <= horizon_s + 1e-12)
    return frame, np.where(valid, tau, np.nan), valid


def frame_pairs(
    times_s: np.ndarray, horizon_s: float, pairs_per_chunk: int = PAIRS_PER_CHUNK
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Every frame pair ``(i, j)`` with 0 < t_j - t_i <= horizon and its ``tau``, each ``(N,)``,
    in chunks of at most about ``pairs_per_chunk`` pairs (memory bounded by it). The most future
    frames ANY frame has (:func:`_horizon_frames`) are looked at, so a frame after a gap in the
    stamps keeps every pair within the horizon."""
    T = len(times_s)
    K = _horizon_frames(times_s, horizon_s)
    for rows in _chunks(T, K, pairs_per_chunk):
        frame, tau, valid = _future_frames(times_s, horizon_s, K, rows)
        i = np.broadcast_to(np.arange(T)[rows][:, None], frame.shape)
        yield i[valid], frame[valid], tau[valid]


def _chunks(T: int, K: int, pairs_per_chunk: int) -> Iterator[slice]:
    """Consecutive frame ranges of ``T`` frames with ``K`` future frames each, about
    ``pairs_per_chunk`` pairs per range (at least one frame)."""
    step = max(1, pairs_per_chunk // K)
    return (slice(a, min(a + step, T)) for a in range(0, T, step))


def containment(
    reach: HumanReach,
    times_s: np.ndarray,
    y: np.ndarray,
    horizon_s: float,
    models: tuple[str, ...] = MODELS,
    n_worst: int = 5,
    faulted: np.ndarray | None = None,
    effective_of: tuple[str, ...] | None = None,
    pairs_per_chunk: int = PAIRS_PER_CHUNK,
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
    The frames are analysed in chunks of about ``pairs_per_chunk`` frame pairs (memory bounded
    by it, not by the recording); the rates are estimated once over the whole recording, so
    the result does not depend on the chunking.
    """
    reach = HumanReach(replace(reach.params, delay_s=0.0))
    T = y.shape[0]
    K = _horizon_frames(times_s, horizon_s)
    rs = rates(reach, times_s, y, models)
    job = _Job(reach, times_s, y, horizon_s, models, K, rs, n_worst, effective_of)
    f = None if faulted is None else np.asarray(faulted, bool)
    parts = [_chunk(job, rows, None if f is None else f[rows])
             for rows in _chunks(T, K, pairs_per_chunk)]  # fmt: skip
    return {m: _merge([p[m] for p in parts], reach.skeleton.joints, n_worst) for m in parts[0]}


@dataclass(frozen=True)
class _Job:
    """What every chunk of one :func:`containment` call shares."""

    reach: HumanReach
    times_s: np.ndarray
    y: np.ndarray
    horizon_s: float
    models: tuple[str, ...]
    K: int
    rates: Rates
    n_worst: int
    effective_of: tuple[str, ...] | None


def _chunk(job: _Job, rows: slice, faulted: np.ndarray | None) -> dict[str, Containment]:
    """:func:`containment` of the measurements ``rows`` (frame numbers stay the recording's);
    ``faulted (F,)``: theirs."""
    reach, K = job.reach, job.K
    frame, tau, valid = _future_frames(job.times_s, job.horizon_s, K, rows)
    occ = _occupancies_at(job, tau, valid, rows)
    fut = as_f8(job.y[frame])  # (F, K, J, 3)
    names = reach.skeleton.joints
    F, J = len(frame), len(names)
    tally = (names, job.times_s[rows], tau, job.n_worst, rows.start)
    results: dict[str, Containment] = {}
    eff_inside = np.ones((F, K, J), dtype=bool)
    eff_worst = np.full((F, K, J), -np.inf)
    for m in job.models:
        o = occ[m]
        # A joint is contained when every capsule that must hold it does.
        inside = np.ones((F, K, J), dtype=bool)
        worst_excess = np.full((F, K, J), -np.inf)
        known = np.ones((F, K, J), dtype=bool)
        cover_joints(fut, as_f8(o.ends), as_f8(o.radius), *reach.coverage[m], inside,
                     worst_excess, known)  # fmt: skip
        v3 = valid[:, :, None] & known
        results[m] = _tally(m, inside, worst_excess, v3, *tally)
        results[m].unavailable = int((valid[:, :, None] & ~known).sum())
        if job.effective_of is None or m in job.effective_of:
            eff_inside &= inside | ~known
            eff_worst = np.maximum(eff_worst, np.where(known, worst_excess, -np.inf))
    v3 = np.broadcast_to(valid[:, :, None], (F, K, J))
    eff = _tally(EFFECTIVE, eff_inside, eff_worst, v3, *tally)
    if faulted is not None:
        eff.unflagged = int((~eff_inside & v3 & ~faulted[:, None, None]).sum())
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
    first_frame: int,
) -> Containment:
    """A :class:`Containment` from ``inside``, ``worst_excess`` and the checked ``v3`` (all
    ``(F, K, J)``, measurements from frame ``first_frame`` on, at ``times_s (F,)``): counts,
    misses per joint and the ``n_worst`` escapes."""
    res = Containment(model, int(v3.sum()), int((inside & v3).sum()))
    miss = ~inside & v3
    at = np.flatnonzero(miss)  # the misses only (a sound set has none)
    for j, n in zip(*np.unique(at % miss.shape[2], return_counts=True), strict=True):
        res.misses_per_joint[names[j]] = int(n)
    # an excess that overflowed (coordinates near the float limit) is a miss by more than any
    # finite one: listed first, never dropped from the list as not finite
    by = np.nan_to_num(worst_excess.ravel()[at], nan=np.inf, posinf=np.inf)
    for o in np.argsort(by, kind="stable")[::-1][:n_worst]:
        i, k, j = np.unravel_index(at[o], miss.shape)
        res.worst.append(Miss(names[j], first_frame + int(i), float(times_s[i]),
                              float(tau[i, k]), float(by[o])))  # fmt: skip
    return res


def _merge(parts: list[Containment], names: tuple[str, ...], n_worst: int) -> Containment:
    """One :class:`Containment` from the chunks' of one model: counts summed, misses per joint
    in the skeleton's order, the ``n_worst`` largest escapes of all."""
    if len(parts) == 1:
        return parts[0]
    screened = all(p.unflagged is not None for p in parts)
    out = Containment(
        parts[0].model,
        sum(p.checked for p in parts),
        sum(p.contained for p in parts),
        unavailable=sum(p.unavailable for p in parts),
        unflagged=sum(p.unflagged or 0 for p in parts) if screened else None,
    )
    for j in names:
        n = sum(p.misses_per_joint.get(j, 0) for p in parts)
        if n:
            out.misses_per_joint[j] = n
    out.worst = sorted((w for p in parts for w in p.worst), key=lambda w: -w.excess_m)[:n_worst]
    return out


def _occupancies_at(
    job: _Job, tau: np.ndarray, valid: np.ndarray, rows: slice
) -> dict[str, Occupancy]:
    """Each model's sets at the instants ``tau (F, K)`` after the frames ``rows`` (invalid
    entries are evaluated at the horizon and not used): ``(F, K, C)``. One call when every
    frame's valid offsets are those of the frame with the most (uniform sampling), else one
    per frame."""
    reach, times_s, y, models, rs = job.reach, job.times_s, job.y, job.models, job.rates
    filled = np.where(valid, tau, job.horizon_s)
    ref = filled[np.argmax(valid.sum(axis=1))]
    frames = np.arange(len(times_s))[rows]
    if np.all(np.abs(np.where(valid, filled - ref, 0.0)) <= 1e-12):
        return occupancies(reach, times_s, y, ref, ref, models, frames, rs)
    ends: dict[str, list[np.ndarray]] = {m: [] for m in models}
    radius: dict[str, list[np.ndarray]] = {m: [] for m in models}
    names: dict[str, tuple[str, ...]] = {}
    for i, frame in enumerate(frames):
        row = occupancies(reach, times_s, y, filled[i], filled[i], models, frame[None], rs)
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
    # the sampled frames' sets only (their rates from the whole recording's history)
    occ = occupancies(reach, times_s, y, np.zeros(1), t, models, frames)
    rows = np.arange(len(frames))
    out = {}
    known = {m: np.isfinite(occ[m].radius[:, 0]).all(axis=-1) for m in models}
    for m in models:  # frames where a model is unavailable (no velocity estimate) are left out
        o = occ[m]
        vols = [union_volume_mc(o.ends[r, 0], o.radius[r, 0], n_samples, rng)[0]
                for r, ok in zip(rows, known[m]) if ok]  # fmt: skip
        out[m] = float(np.mean(vols)) if vols else float("nan")
    rows = rows[np.all([known[m] for m in models], axis=0)]
    if len(models) > 1 and len(rows):
        maps = [part_capsules(reach, m) for m in models]
        vols = [
            effective_volume_mc(
                [(occ[m].ends[r, 0], occ[m].radius[r, 0]) for m in models], maps, n_samples, rng
            )[0]
            for r in rows
        ]
        out[EFFECTIVE] = float(np.mean(vols))
    return out
