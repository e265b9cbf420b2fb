"""Leave-one-recording-out validation of calibrated parameter sets, and the margin it derives.

A set calibrated on some recordings is sound on them by construction; whether it holds for motion
it was not fitted to is measured by leaving each recording out in turn: calibrate on the others,
then check the one left out. Reported per recording: the effective set's containment (what the
verdict relies on) and its unflagged misses (outside the effective set at a measurement the
conformance monitor had not faulted the person for: the residual risk), and by how much the
recording's own least sound bounds exceed the others' (the ratio per bound).

Calibration (:func:`~sara_app.human.calibrate.calibrate`) takes, per bound, the least value that
contains every recording. For the speed bounds containment only grows with a bound, so the set
fitted on several recordings is the bound-wise maximum of the sets fitted on each alone
(:func:`combine`); leaving one out then costs one fit per recording, not one calibration per
recording of all the others. For the acceleration bounds this is close, not exact (a larger
``a_max`` also shortens the velocity estimator's lag, so containment is not monotone in it:
:func:`~sara_app.human.calibrate.fit_acceleration`); every figure reported here is measured on
the combined set itself, so it is true of the set that was checked.

The margin: the largest ratio over the left-out recordings (at least 1), per kind of bound
(speeds, accelerations, the arm model's rates). A set fitted on all recordings and widened by it
would have contained every recording when that recording was the one not fitted; that is the
claim the validation supports, no more.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from sara_app.human.analysis import EFFECTIVE, containment
from sara_app.human.calibrate import calibrate
from sara_app.human.intake import screen_recording
from sara_app.human.params import ParamSet, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.recording import Recording


@dataclass
class HeldOut:
    """One recording checked against the set fitted on the others."""

    recording: str
    checked: int
    contained: int
    unflagged: int
    v_ratio: float
    """The recording's own least sound speed bound over the others' set's, worst joint."""
    a_ratio: float
    arm_ratio: float

    @property
    def share(self) -> float:
        return self.contained / self.checked if self.checked else float("nan")


@dataclass
class Validation:
    horizon_s: float
    models: tuple[str, ...]
    rows: list[HeldOut]

    @property
    def margin(self) -> tuple[float, float, float]:
        """``(speeds, accelerations, arm rates)``: the factors (>= 1) the set fitted on all
        recordings needs to have contained each one when it was left out."""
        return (
            max([1.0, *(r.v_ratio for r in self.rows)]),
            max([1.0, *(r.a_ratio for r in self.rows)]),
            max([1.0, *(r.arm_ratio for r in self.rows)]),
        )


def _bounds(ps: ParamSet) -> tuple[np.ndarray, np.ndarray]:
    v = np.array([b.v_max_mps for b in ps.joints.values()])
    a = np.array([b.a_max_mps2 for b in ps.joints.values()])
    return v, a


def combine(sets: Sequence[ParamSet], name: str) -> ParamSet:
    """The bound-wise maximum of ``sets`` (same joints and body parts): what calibrating on all
    of their recordings at once gives (see the module notes)."""
    first = sets[0]
    joints = {
        j: b.model_copy(
            update={
                "v_max_mps": max(s.joints[j].v_max_mps for s in sets),
                "a_max_mps2": max(s.joints[j].a_max_mps2 for s in sets),
            }
        )
        for j, b in first.joints.items()
    }
    rates = ("angle_v_max_rad_s", "angle_a_max_rad_s2", "r_v_max_mps", "r_a_max_mps2",
             "shoulder_v_max_mps")  # fmt: skip
    arm = first.arm.model_copy(update={k: max(getattr(s.arm, k) for s in sets) for k in rates})
    return first.model_copy(
        update={
            "name": name,
            "joints": joints,
            "arm": arm,
            "iso_v_max_full_mps": max(s.iso_v_max_full_mps for s in sets),
            "iso_v_max_upper_mps": max(s.iso_v_max_upper_mps for s in sets),
        }
    )


def widened(ps: ParamSet, margin: tuple[float, float, float], name: str) -> ParamSet:
    """``ps`` with its speeds, accelerations and arm rates times ``margin``."""
    mv, ma, mr = margin
    joints = {
        j: b.model_copy(update={"v_max_mps": b.v_max_mps * mv, "a_max_mps2": b.a_max_mps2 * ma})
        for j, b in ps.joints.items()
    }
    a = ps.arm
    arm = a.model_copy(
        update={
            "angle_v_max_rad_s": a.angle_v_max_rad_s * mr,
            "angle_a_max_rad_s2": a.angle_a_max_rad_s2 * mr,
            "r_v_max_mps": a.r_v_max_mps * mr,
            "r_a_max_mps2": a.r_a_max_mps2 * mr,
            "shoulder_v_max_mps": a.shoulder_v_max_mps * mv,
        }
    )
    return ps.model_copy(
        update={
            "name": name,
            "joints": joints,
            "arm": arm,
            "iso_v_max_full_mps": ps.iso_v_max_full_mps * mv,
            "iso_v_max_upper_mps": ps.iso_v_max_upper_mps * mv,
        }
    )


def _ratio(own: np.ndarray, others: np.ndarray) -> float:
    return float(np.max(own / others))


class Screened(NamedTuple):
    """:func:`containment_on`'s result: per model (and :data:`EFFECTIVE`) ``(checked,
    contained, unflagged)`` summed over the recordings, and how many of their frames the
    conformance monitor faulted (the misses there are flagged, not residual risk)."""

    counts: dict[str, tuple[int, int, int]]
    faulted_frames: int


def containment_on(
    ps: ParamSet, recs: Sequence[Recording], horizon_s: float, models: tuple[str, ...],
    effective_of: tuple[str, ...] | None = None,
) -> Screened:  # fmt: skip
    """Per model of ``models`` and the effective set of ``effective_of`` (default ``models``;
    key :data:`EFFECTIVE`): ``(checked, contained, unflagged)`` under ``ps`` summed over
    ``recs``, each screened by a fresh intake (the monitor's faults clear its misses), and the
    frames it faulted."""
    out: dict[str, tuple[int, int, int]] = {}
    n_faulted = 0
    for rec in recs:
        reach = HumanReach(to_reach_params(ps, rec.kind))
        fault = screen_recording(reach.params, rec).faulted
        n_faulted += int(fault.sum())
        res = containment(reach, rec.times_s, rec.positions_m, horizon_s, models,
                          faulted=fault, effective_of=effective_of)  # fmt: skip
        for m, c in res.items():
            k, n, u = out.get(m, (0, 0, 0))
            out[m] = (k + c.checked, n + c.contained, u + (c.unflagged or 0))
    return Screened(out, n_faulted)


def leave_one_out(
    base: ParamSet,
    recs: list[list[Recording]],
    names: list[str],
    horizon_s: float,
    models: tuple[str, ...],
    delta_y_m: float | None = None,
) -> tuple[Validation, list[ParamSet]]:
    """Every recording (at least two; each given as its pieces without reconstruction failures:
    :func:`~sara_app.human.failures.split`, named by ``names``) checked against the set fitted
    on the others (the effective set of ``models``); also returns each recording's own fit."""
    own = [calibrate(base, r, horizon_s, f"fit_{n}", delta_y_m)[0] for r, n in zip(recs, names)]
    rows = []
    for i, (parts, name) in enumerate(zip(recs, names)):
        others = combine([p for k, p in enumerate(own) if k != i], "others")
        held = containment_on(others, parts, horizon_s, models).counts
        checked, contained, unflagged = held[EFFECTIVE]
        (v_own, a_own), (v_oth, a_oth) = _bounds(own[i]), _bounds(others)
        arm_ratio = own[i].arm.r_v_max_mps / others.arm.r_v_max_mps
        rows.append(HeldOut(name, checked, contained, unflagged, _ratio(v_own, v_oth),
                            _ratio(a_own, a_oth), arm_ratio))  # fmt: skip
    return Validation(horizon_s, models, rows), own


def format_validation(val: Validation) -> str:
    mv, ma, mr = val.margin
    lines = [
        f"leave-one-recording-out validation (horizon {val.horizon_s} s, effective set of "
        f"{', '.join(val.models)}): each recording against the set fitted on the others",
        f"  {'recording':28s} {'contained':>10s} {'misses':>8s} {'unflagged':>9s} "
        f"{'v ratio':>8s} {'a ratio':>8s} {'arm':>6s}",
    ]
    for r in val.rows:
        lines.append(
            f"  {r.recording:28s} {100 * r.share:9.4f}% {r.checked - r.contained:8d} "
            f"{r.unflagged:9d} {r.v_ratio:8.3f} {r.a_ratio:8.3f} {r.arm_ratio:6.3f}"
        )
    lines.append(f"  margin the shipped set needs: speeds x{mv:.3f}, accelerations x{ma:.3f}, "
                 f"arm rates x{mr:.3f}")  # fmt: skip
    return "\n".join(lines)
