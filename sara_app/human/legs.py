"""Legs that the tracker does not measure, bounded from above: the vertical bound of a person
seen by an upper-body tracker at a bench.

An upper-body tracker measures the head, neck, pelvis, shoulders, elbows and wrists; the legs'
sets are then balls at the pelvis as large as a leg's reach (:mod:`sara_app.human.widening`).
In a bench cell those balls reach over the bench top, where the robot works, although no
standing person's knee or foot gets there. The argument that bounds them:

1. *Legs below the pelvis* (assumed for the activity, fitted): at any time every joint of leg
   part ``p`` (hip and knee for a thigh, knee and ankle for a shin, the ankle for a foot) is at
   most ``above_pelvis_m[p]`` above the pelvis joint (negative: below it). Trackers put the
   pelvis at the pelvis's centre (Azure Kinect) or at the hips' midpoint (BlazePose), which in
   the recordings lies about 9 cm lower: the fit measures from the lower of the two, so the
   bound holds for either. It holds for people
   who stand, walk and work with their feet on the floor; it does not hold for kneeling on the
   bench, climbing or kicking high. Fitted to the full-body recordings of the activity (maximum
   over every frame) plus a margin; validated by leaving each recording out
   (:func:`leave_one_out`).
2. *The pelvis rises slowly* (fitted and monitored): over the horizon ``tau`` the pelvis rises at
   most ``rise_max_mps * tau``. The pelvis is measured, so the conformance monitor checks it
   (:mod:`sara_app.human.conformance`, quantity ``rise``); a person who rises faster is a fault
   (the robot stays on its verified failsafe).
3. *Noise*: the measured pelvis lies within ``delta_y`` (plus any widening of the pelvis joint)
   of the true one.

Together: every point of leg part ``p`` of a person measured at time ``t0`` lies at ``t0 + tau``
at most ``z_cap(p, tau) = z_pelvis + delta_y + e + above_pelvis_m[p] + r_p + rise_max_mps *
tau`` high (``r_p`` the part's half thickness), whatever the part's horizontal reach. The SSM
check (:mod:`sara_app.safety.ssm_kernels`) intersects each model's set of a leg part with the
half-space below ``z_cap``: a robot link whose lowest point is above it cannot touch the part.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sara_app.errors import InputError
from sara_app.human.analysis import frame_pairs
from sara_app.human.conformance import Monitor
from sara_app.human.params import LEG_PARTS, LegHeights, ReachParams
from sara_app.human.recording import Recording
from sara_app.human.skeleton import FULL_BODY_PARTS, FULL_JOINTS

PELVIS = FULL_JOINTS.index("pelvis")
_HIPS = [FULL_JOINTS.index("l_hip"), FULL_JOINTS.index("r_hip")]
_PART_JOINTS = np.array(
    [[FULL_JOINTS.index(j) for j in FULL_BODY_PARTS[p]] for p in LEG_PARTS], dtype=np.int64
)  # (6, 2)


@functools.lru_cache(maxsize=64)
def no_bounds(H: int, P: int) -> np.ndarray:
    """A read-only ``(H, P, 2)`` of no height bounds (``base = inf``, rate 0): the checks'
    bounds for people without any, one array per shape (no allocation per cycle)."""
    none = np.zeros((H, P, 2))
    none[:, :, 0] = np.inf
    none.flags.writeable = False
    return none


def leg_caps(params: ReachParams, y: np.ndarray, extra_m: float | np.ndarray) -> np.ndarray | None:
    """``(P, 2)`` per body part the height bound's base (m, world z) and its rise rate (m/s):
    ``z_cap(tau) = base + rate * tau``, ``tau`` the time since the measurement ``y (J, 3)``
    (see the module notes); ``base = inf`` for a part it does not bound. ``extra_m``: the
    joints' uncertainty beyond ``delta_y`` (one value or ``(J,)``). None when the parameter set
    bounds no leg."""
    above = params.leg_above_pelvis_m
    finite = np.isfinite(above)
    if not finite.any():
        return None
    e = float(np.broadcast_to(np.asarray(extra_m, float), (y.shape[0],))[PELVIS])
    z0 = float(y[PELVIS, 2]) + params.delta_y_m + max(e, 0.0)
    caps = np.empty((above.shape[0], 2))
    caps[:, 0] = np.where(finite, z0 + above + params.half_thickness_m, np.inf)
    caps[:, 1] = np.where(finite, params.pelvis_rise_mps, 0.0)
    return caps


def _leg_tops(rec: Recording) -> tuple[np.ndarray, np.ndarray]:
    """``(top (T, 6), pelvis (T,))``: each leg part's highest joint and the pelvis, world z;
    the pelvis is the lower of the pelvis joint and the hips' midpoint (trackers place it at
    either: the bound then holds for both)."""
    if rec.kind != "full":
        raise InputError(
            f"recording {rec.name!r} is {rec.kind!r}: the legs' heights need a full-body "
            "recording (valid: kind 'full')"
        )
    z = rec.positions_m[:, :, 2]
    mid_hips = z[:, _HIPS].mean(axis=1)
    return z[:, _PART_JOINTS].max(axis=2), np.minimum(z[:, PELVIS], mid_hips)


def _spans(rec: Recording, horizon_s: float) -> range:
    """Frame spans ``1 .. n`` with ``n`` frames within ``horizon_s``."""
    dt = float(np.median(np.diff(rec.times_s)))
    return range(1, max(1, int(round(horizon_s / dt))) + 1)


def fit_legs(
    recs: Sequence[Recording], horizon_s: float = 0.5, margin_m: float = 0.0,
    rise_margin: float = 1.0,
) -> LegHeights:  # fmt: skip
    """The tightest :class:`LegHeights` the recordings need (rounded up to 1 cm and 0.05 m/s):
    ``above_pelvis_m`` the largest height of each leg part's joints over the pelvis (left and
    right alike), plus ``margin_m``; ``rise_max_mps`` the pelvis's fastest rise over spans up
    to ``horizon_s``, times ``rise_margin``."""
    if not recs:
        raise InputError("no recordings to fit the legs' heights to; expected at least one")
    above = np.full(len(LEG_PARTS), -np.inf)
    rise = 0.0
    for rec in recs:
        top, zp = _leg_tops(rec)
        above = np.maximum(above, (top - zp[:, None]).max(axis=0))
        t = rec.times_s
        for k in _spans(rec, horizon_s):
            if k < len(t):
                rise = max(rise, float(((zp[k:] - zp[:-k]) / (t[k:] - t[:-k])).max()))
    # a person's left and right are alike: each side takes the higher of the two
    kinds = [p.split("_", 1)[1] for p in LEG_PARTS]  # thigh, shin, foot
    worst = {k: max(a for a, j in zip(above, kinds, strict=True) if j == k) for k in kinds}
    above = np.array([worst[k] for k in kinds])
    above_m = np.ceil((above + margin_m) * 100.0) / 100.0
    rise_mps = max(math.ceil(rise * rise_margin * 20.0) / 20.0, 0.05)
    return LegHeights(
        above_pelvis_m={p: float(a) for p, a in zip(LEG_PARTS, above_m, strict=True)},
        rise_max_mps=rise_mps,
    )


@dataclass(frozen=True)
class LegContainment:
    """One recording against a vertical bound over a horizon: ``checked`` (start frame, later
    frame, leg part) triples, ``misses`` of them above the bound, the worst excess (m) and the
    ``unflagged`` misses: from a start frame at which the monitor's rise check alone
    (:func:`rise_flagged`) had not faulted the person."""

    recording: str
    horizon_s: float
    checked: int
    misses: int
    worst_excess_m: float
    unflagged: int = 0

    @property
    def contained_pct(self) -> float:
        return 100.0 * (1.0 - self.misses / self.checked) if self.checked else 100.0


def containment(
    rec: Recording, legs: LegHeights, horizon_s: float, delta_y_m: float = 0.0
) -> LegContainment:
    """Every frame ``t`` and every later frame within ``horizon_s``: is each leg part's highest
    joint at ``t + tau`` at most ``above_pelvis_m + rise_max_mps * tau`` above the pelvis at
    ``t`` (the bound the check uses, without the noise and thickness terms)? The misses from
    frames the monitor had flagged (its rise check with noise bound ``delta_y_m``) are counted
    apart."""
    top, zp = _leg_tops(rec)
    above = np.array([legs.above_pelvis_m[p] for p in LEG_PARTS])
    flagged = rise_flagged(rec, legs.rise_max_mps, delta_y_m)
    checked = misses = unflagged = 0
    worst = -np.inf
    for i, j, tau in frame_pairs(rec.times_s, horizon_s):  # every pair within the horizon
        excess = top[j] - (zp[i, None] + above + legs.rise_max_mps * tau[:, None])  # (N, parts)
        miss = excess > 0.0
        checked += miss.size
        misses += int(miss.sum())
        unflagged += int(miss[~flagged[i]].sum())
        worst = max(worst, float(excess.max(initial=-np.inf)))
    return LegContainment(rec.name, horizon_s, checked, misses, worst, unflagged)


def rise_flagged(rec: Recording, rise_max_mps: float, delta_y_m: float = 0.0) -> np.ndarray:
    """``(T,)``: the conformance monitor faults the person at each frame for the pelvis's rise
    alone (the recording as the measurement, every joint trusted; speed and acceleration
    unbounded, so this flags no more than a live monitor would)."""
    J = rec.positions_m.shape[1]
    rise = np.full(J, np.inf)
    rise[PELVIS] = rise_max_mps
    inf = np.full(J, np.inf)
    mon = Monitor(rec.joints, inf, inf, rise_max_mps=rise)
    trusted, jump = np.ones(J, bool), np.zeros(J)
    out = np.zeros(rec.n_frames, bool)
    for i, (ti, yi) in enumerate(zip(rec.times_s, rec.positions_m, strict=True)):
        mon.observe(float(ti), yi, trusted, delta_y_m, jump, rise=True)
        out[i] = mon.violating and bool(mon.last)
    return out


def leave_one_out(
    recs: Sequence[Recording], horizons_s: Sequence[float] = (0.1, 0.2, 0.5),
    margin_m: float = 0.0, delta_y_m: float = 0.0, sources: Sequence[str] | None = None,
) -> list[LegContainment]:  # fmt: skip
    """Fit on every recording but one (:func:`fit_legs`, ``margin_m``), check the one left
    out at each horizon (the monitor's noise bound ``delta_y_m``); one row per recording and
    horizon. ``sources``: the recording each of ``recs`` comes from (pieces of one recording,
    e.g. its walking pieces, are left out together: they are not independent); default each
    its own."""
    src = [str(i) for i in range(len(recs))] if sources is None else list(sources)
    if len(src) != len(recs):
        raise InputError(f"{len(src)} sources for {len(recs)} recordings; expected one each")
    if len(set(src)) < 2:
        raise InputError(f"leave-one-out needs at least 2 recordings; got {len(set(src))}")
    rows = []
    for i, rec in enumerate(recs):
        others = [r for j, r in enumerate(recs) if src[j] != src[i]]
        legs = fit_legs(others, max(horizons_s), margin_m)
        rows += [containment(rec, legs, h, delta_y_m) for h in horizons_s]
    return rows


def fit_validated(
    recs: Sequence[Recording], horizons_s: Sequence[float] = (0.1, 0.2, 0.5),
    delta_y_m: float = 0.0, sources: Sequence[str] | None = None,
) -> tuple[LegHeights, list[LegContainment], float]:  # fmt: skip
    """Leave each recording out (:func:`leave_one_out`, no margin; ``sources`` as there),
    derive the margin from the worst excess of a recording left out (rounded up to 1 cm) and
    fit on all recordings with it: ``(legs, the left-out rows, margin_m)``."""
    rows = leave_one_out(recs, horizons_s, delta_y_m=delta_y_m, sources=sources)
    worst = max(r.worst_excess_m for r in rows)
    margin_m = max(0.0, math.ceil(worst * 100.0) / 100.0)
    return fit_legs(recs, max(horizons_s), margin_m), rows, margin_m


def format_containment(rows: Sequence[LegContainment]) -> str:
    """One line per recording: contained share, misses and worst excess per horizon."""
    by: dict[str, list[LegContainment]] = {}
    for r in rows:
        by.setdefault(r.recording, []).append(r)
    return "\n".join(
        f"  {name}: "
        + "; ".join(
            f"{r.horizon_s:g} s {r.contained_pct:.3f} % ({r.misses} misses, {r.unflagged} "
            f"unflagged, worst {100 * r.worst_excess_m:+.1f} cm)"
            for r in rs
        )
        for name, rs in by.items()
    )
