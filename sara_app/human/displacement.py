"""How far a joint gets within a time: the displacement bound of R_VEL, fitted to recordings.

SaRA's R_VEL grows a joint's ball by ``v_max tau`` (Schepp et al. 2022 Sec. II-B): the joint at its
peak speed for the whole horizon. Real motion does not keep its peak: a hammering wrist that
reaches 7 m/s for a few frames is 0.7-0.8 m from where it was 0.2 s before, not 1.4 m, because
the swing turns back and the arm's length bounds it. The displacement bound ``D_j(tau)`` is the
largest distance between joint ``j``'s positions ``tau`` apart over the recordings of the
activity (beyond the measurement's ``delta_y``, as ``v_max`` is fitted), on a grid of cells
``(i step, (i + 1) step]``, made non-decreasing (a set at an interval's end must cover the
interval); R_VEL then grows by ``min(v_max tau, D_j(tau))``
(:func:`~sara_app.human.reach_kernels.displacement_bound`).

Which joints: by default the upper body's (what an upper-body tracker measures, pelvis
included); the legs keep ``v_max tau``. Standing work moves the legs little, so a table fitted to
it would make every walk past the bench a violation (CMU 02_01's walk: 81 % of its frames
faulted), while the robot at a bench meets hands, arms and heads. Every bounded joint is allowed
at least ``FLOOR_MPS`` sustained.

What it assumes: the person does what the recordings do, as every fitted bound does; where the
recordings never took a joint farther within ``tau``, nobody will. That is checked, not trusted:
the conformance monitor measures every trusted joint's distance to where it was up to the
table's horizon back and faults the person beyond it (:mod:`sara_app.human.conformance`), and
:func:`leave_one_out` measures how often it holds on a recording the bound was not fitted to.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sara_app.errors import InputError, ParameterError
from sara_app.human.analysis import EFFECTIVE, frame_pairs
from sara_app.human.params import DisplacementBound, ParamSet
from sara_app.human.recording import Recording
from sara_app.human.skeleton import FULL_JOINTS, UPPER_JOINTS
from sara_app.human.validation import containment_on

STEP_S = 0.01
"""The table's cell width: a tenth of the shortest horizon reported (0.1 s)."""
FLOOR_MPS = 2.0
"""The sustained speed every bounded joint is allowed at least: ISO 13855's approach speed (the
larger of its two, 2.0 m/s; Pereira & Althoff 2016 Sec. III-A use it for the full body), so that
keeping up that speed is no violation by itself (a walk past the bench: CMU 02_01's, at 1.3 m/s
with its arms swinging, stays within bench_work's table; a brisker one may not)."""


def cells(tau_s: np.ndarray, step_s: float) -> np.ndarray:
    """The cell of each time ``tau_s (n,)``: ``ceil(tau / step) - 1`` (at least 0), as the
    compiled sets look it up (:func:`~sara_app.human.reach_kernels.displacement_bound`)."""
    return np.maximum(np.ceil(tau_s / step_s).astype(np.int64) - 1, 0)


def fit_displacement(
    recs: Sequence[Recording],
    delta_y_m: float,
    horizon_s: float,
    step_s: float = STEP_S,
    trusted: Sequence[np.ndarray] | None = None,
) -> np.ndarray:
    """``(J, N)`` in the full skeleton's joint order, ``N = ceil(horizon / step)``: per joint and
    cell the largest ``|y(t + tau) - y(t)| - delta_y`` over the frame pairs of ``recs`` with
    ``tau`` in the cell (or within a millionth of a step above its end; ``trusted [(T, J)]``:
    the joint-frames to use, None: all), non-decreasing along the cells; a cell no pair falls in
    takes the next one's value. ``nan`` for a joint no recording measures (an upper-body
    recording measures the first joints only) and past the longest pair of a joint's
    recordings (recordings shorter than the horizon)."""
    if not (step_s > 0 and horizon_s >= step_s):
        raise ParameterError(f"displacement horizon {horizon_s} s, step {step_s} s; expected "
                             "0 < step <= horizon")  # fmt: skip
    n = int(math.ceil(horizon_s / step_s - 1e-9))
    best = np.full((len(FULL_JOINTS), n), -np.inf)
    for r, rec in enumerate(recs):
        y, t = rec.positions_m, rec.times_s
        J = y.shape[1]
        ok = np.ones(y.shape[:2], bool) if trusted is None else np.asarray(trusted[r], bool)
        # the pairs the fits and the containment check take (every frame's, after a gap in the
        # stamps too), to the last cell's end and its rounding
        for i, j, tau in frame_pairs(t, (n + 1e-6) * step_s):
            # a pair within rounding of a cell's end counts in that cell (and so, the table
            # being non-decreasing, in the next): stamps 50 ms apart come out 0.05 or 0.05 + 2e-17
            c = cells(tau - 1e-6 * step_s, step_s)
            inside = c < n
            d = np.linalg.norm(y[j] - y[i], axis=-1) - delta_y_m  # (N, J)
            d = np.where(ok[j] & ok[i] & inside[:, None], d, -np.inf)
            for q in range(J):
                np.maximum.at(best[q], c[inside], d[inside, q])
    out = np.full_like(best, np.nan)
    for q in range(best.shape[0]):
        row = best[q]
        seen = np.flatnonzero(np.isfinite(row))
        if not seen.size:
            continue
        last = seen[-1]  # cells past the longest pair seen stay nan: no data, no claim
        filled = row[: last + 1].copy()
        nxt = row[last]  # a cell without pairs: the next cell's value (larger, so sound)
        for k in range(last, -1, -1):
            nxt = filled[k] = row[k] if np.isfinite(row[k]) else nxt
        out[q, : last + 1] = np.maximum.accumulate(np.maximum(filled, 0.0))
    return out


@dataclass(frozen=True)
class Shaping:
    """How a fitted table becomes the set's bound: ``joints`` the joints it bounds (the others
    keep ``v_max tau``), each row times ``margin`` (>= 1) and at least ``floor_mps`` times
    ``tau`` (a sustained speed every bounded joint is allowed whatever the recordings did)."""

    joints: tuple[str, ...] = UPPER_JOINTS
    margin: float = 1.0
    floor_mps: float = FLOOR_MPS

    def __post_init__(self) -> None:
        if not self.margin >= 1.0:
            raise ParameterError(f"displacement margin {self.margin}; expected >= 1")
        if not 0.0 <= self.floor_mps <= 20.0:
            raise ParameterError(f"displacement floor {self.floor_mps} m/s; expected 0 to 20")
        unknown = [j for j in self.joints if j not in FULL_JOINTS]
        if unknown:
            raise ParameterError(f"joint {unknown[0]!r} is not one of {', '.join(FULL_JOINTS)}")


def to_bound(
    table_m: np.ndarray, step_s: float, ps: ParamSet, shaping: Shaping = Shaping()
) -> DisplacementBound:
    """The set's :class:`DisplacementBound` from a fitted ``table_m (J, N)`` shaped by
    ``shaping``, rounded up to the millimetre; a joint it does not bound, and a cell without
    data (``nan``), gets ``v_max`` times the cell's end (no tightening), the row non-decreasing."""
    ends = step_s * np.arange(1, table_m.shape[1] + 1)
    rows = {}
    for q, j in enumerate(FULL_JOINTS):
        v_max = ps.joints[j].v_max_mps * ends
        row = v_max
        if j in shaping.joints:
            fitted = np.maximum(table_m[q] * shaping.margin, shaping.floor_mps * ends)
            row = np.where(np.isfinite(table_m[q]), np.minimum(fitted, v_max), v_max)
        rows[j] = [math.ceil(float(x) * 1000.0) / 1000.0 for x in np.maximum.accumulate(row)]
    return DisplacementBound(step_s=step_s, max_m=rows)


def with_bound(ps: ParamSet, bound: DisplacementBound | None) -> ParamSet:
    """``ps`` with the displacement bound ``bound`` (None: none)."""
    return ps.model_copy(update={"displacement": bound})


@dataclass(frozen=True)
class HeldOut:
    """One recording checked against ``base`` with the table fitted on the others: per horizon
    ``(checked, contained, unflagged)`` of the effective set (what the verdict uses), and the
    factor by which its own table exceeds the others' at worst (1: within)."""

    recording: str
    by_horizon: dict[float, tuple[int, int, int]]
    ratio: float


def leave_one_out(
    base: ParamSet,
    pieces: Sequence[Sequence[Recording]],
    trusted: Sequence[Sequence[np.ndarray]],
    names: Sequence[str],
    horizons_s: Sequence[float] = (0.1, 0.2, 0.5),
    models: tuple[str, ...] = ("acc", "vel", "pos", "combined"),
    step_s: float = STEP_S,
    shaping: Shaping = Shaping(),
) -> list[HeldOut]:
    """Each recording (``pieces[i]``, its pieces without reconstruction failures, with the
    gate's ``trusted`` masks) against ``base`` plus the table fitted on the OTHER recordings:
    containment of the effective set of ``models`` and its unflagged misses (the monitor checks
    that table too). ``base``'s own bounds are left as they are, so what is measured is the
    table's generalisation."""
    if len(pieces) < 2:
        raise InputError(f"leave-one-out needs at least 2 recordings; got {len(pieces)}")
    horizon = max(horizons_s)
    own = [fit_displacement(p, base.delta_y_m, horizon, step_s, t) for p, t in zip(pieces, trusted)]
    rows = []
    for i, name in enumerate(names):
        others = np.fmax.reduce([o for k, o in enumerate(own) if k != i])
        table = np.maximum.accumulate(others, axis=1)
        bounded = with_bound(base, to_bound(table, step_s, base, shaping))
        counts = {
            h: containment_on(bounded, pieces[i], h, models).counts[EFFECTIVE] for h in horizons_s
        }
        bounded_rows = np.isin(FULL_JOINTS, shaping.joints)[:, None]
        fitted = np.isfinite(own[i]) & np.isfinite(others) & bounded_rows
        excess = own[i][fitted] / np.maximum(others[fitted], 1e-3)
        rows.append(HeldOut(name, counts, max(1.0, float(excess.max(initial=1.0)))))
    return rows


def format_held_out(rows: Sequence[HeldOut]) -> str:
    """One line per recording: effective-set containment, misses and unflagged per horizon."""
    lines = []
    for r in rows:
        parts = [f"{h:g} s {100 * n / max(k, 1):.3f} % ({k - n} misses, {u} unflagged)"
                 for h, (k, n, u) in r.by_horizon.items()]  # fmt: skip
        lines.append(f"  {r.recording}: " + "; ".join(parts) + f"; own table x{r.ratio:.2f}")
    return "\n".join(lines)
