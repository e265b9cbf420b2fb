"""Fit per-joint bounds from recordings so that the models contain them.

For every recording, every frame i as a measurement and every later frame j within the horizon
(tau = t_j - t_i), a joint's displacement must fit the model:

- R_VEL / ISO 13855 / R_POS roots: |y_j - y_i| <= delta_y + v_max tau, so the least sound
  v_max is max (|y_j - y_i| - delta_y) / tau;
- R_ACC: |y_j - y_i - v_hat_i tau| <= delta_y + dv_i tau + a_max tau^2 / 2, where the velocity
  error bound dv_i itself grows with a_max (``velocity.py``): a fixed-point iteration on a_max;
- the arm model: its four rate limits are scaled together (bisection) until every arm joint is
  contained, its shoulder speed is the shoulders' v_max.

Tracker noise is fitted apart from human dynamics: ``delta_y`` is the calibration's argument
(the tracker's noise bound), not absorbed into the bounds; the report gives each joint's largest
one-frame chord deviation ``|y_i - (y_(i-1) + y_(i+1)) / 2|``, which noise alone keeps below
``2 delta_y`` (a larger value is either a glitch or acceleration beyond ``2 (d - 2 delta_y) /
dt^2``, which the bounds then must allow).

Frames are screened first as a live cell would (:func:`sara_app.human.intake.screen`, with no
speed bound: a joint faster than the base set allows is motion to fit): a joint
the tracking gate distrusts in a frame (bone, frozen) is excluded from every pair it is in, and
the report lists those frames. The bounds also cover what the conformance monitor needs on the
recordings (its values do not depend on the bounds), so a cell running the calibrated set does
not fault on the motion it was calibrated on.

Otherwise nothing is dropped: each bound comes with the frames that drive it (recording, time,
horizon, value), so a one-frame tracking glitch shows up in the report and a person judges it.
Recordings are taken as ground truth with zero latency (the delay is a property of the sensor
in the cell; the fitted bounds hold for motion, whatever delay is added later).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sara_app.errors import InputError, ParameterError
from sara_app.human.analysis import containment, frame_pairs
from sara_app.human.failures import Failure, pieces, runs
from sara_app.human.intake import screen
from sara_app.human.params import ParamSet, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.recording import Recording
from sara_app.human.skeleton import skeleton
from sara_app.human.velocity import estimate_recording


@dataclass
class Driver:
    """A frame pair that drives a bound."""

    recording: str
    t_s: float
    tau_s: float
    value: float


@dataclass
class CalibrationReport:
    horizon_s: float
    v_max: dict[str, float] = field(default_factory=dict)
    a_max: dict[str, float] = field(default_factory=dict)
    drivers_v: dict[str, list[Driver]] = field(default_factory=dict)
    drivers_a: dict[str, list[Driver]] = field(default_factory=dict)
    iso_v_max: float = 0.0
    arm_scale: float = 1.0
    shoulder_v_max: float = 0.0
    delta_y_m: float = 0.0
    excluded: dict[str, list[str]] = field(default_factory=dict)
    """Per recording: what the tracking gate flagged (those joint-frames are left out)."""
    noise_m: dict[str, float] = field(default_factory=dict)
    """Per joint: the largest one-frame chord deviation over the recordings."""
    monitor_v: dict[str, float] = field(default_factory=dict)
    monitor_a: dict[str, float] = field(default_factory=dict)
    combined_raised: dict[str, float] = field(default_factory=dict)
    """Joints whose speed bound was raised until the combined model contains the recordings."""


def _top(
    values: np.ndarray, rec: Recording, i: np.ndarray, tau: np.ndarray, n: int, so_far: list
) -> list:
    """The ``n`` largest of ``so_far`` and the pairs' ``values (N,)`` as drivers."""
    order = np.argsort(values)[::-1][:n]
    new = [Driver(rec.name, float(rec.times_s[i[o]]), float(tau[o]), float(values[o]))
           for o in order]  # fmt: skip
    return sorted(so_far + new, key=lambda d: -d.value)[:n]


def _trusted(recs: list[Recording], trusted: list[np.ndarray] | None) -> list[np.ndarray]:
    if trusted is None:
        return [np.ones(r.positions_m.shape[:2], bool) for r in recs]
    return trusted


def fit_velocity(
    recs: list[Recording],
    joints: tuple[str, ...],
    delta_y_m: float,
    horizon_s: float,
    n_drivers: int = 3,
    trusted: list[np.ndarray] | None = None,
) -> tuple[np.ndarray, list[list[Driver]]]:
    """Least v_max per joint ``(J,)`` that contains every displacement, and its drivers;
    ``trusted`` ``[(T, J)]`` per recording: joint-frames to use (None: all)."""
    best = np.zeros(len(joints))
    drivers: list[list[Driver]] = [[] for _ in joints]
    for rec, ok in zip(recs, _trusted(recs, trusted)):
        for i, j, tau in frame_pairs(rec.times_s, horizon_s):
            disp = np.linalg.norm(rec.positions_m[j] - rec.positions_m[i], axis=-1)  # (N, J)
            need = np.where(ok[i] & ok[j], (disp - delta_y_m) / tau[:, None], -np.inf)
            J = need.shape[1]  # an upper-body recording fits the upper joints only
            for q in range(J):
                drivers[q] = _top(need[:, q], rec, i, tau, n_drivers, drivers[q])
            best[:J] = np.maximum(best[:J], need.max(axis=0, initial=0.0))  # no pairs: 0
    return best, drivers


def _acc_need(
    recs: list[Recording],
    a: np.ndarray,
    delta_y_m: float,
    horizon_s: float,
    n_drivers: int,
    trusted: list[np.ndarray] | None = None,
) -> tuple[np.ndarray, list[list[Driver]]]:
    """Largest a_max the data need per joint when velocities are estimated with ``a``."""
    J = a.shape[0]
    need_all = np.full(J, -np.inf)
    drivers: list[list[Driver]] = [[] for _ in range(J)]
    for rec, ok_t in zip(recs, _trusted(recs, trusted)):
        Jr = rec.positions_m.shape[1]  # an upper-body recording: its joints only
        v, dv = estimate_recording(rec.times_s, rec.positions_m, delta_y_m, a[:Jr], trusted=ok_t)
        for i, j, tau in frame_pairs(rec.times_s, horizon_s):
            use = ok_t[i] & ok_t[j] & np.isfinite(dv[i])  # (N, J)
            resid = rec.positions_m[j] - rec.positions_m[i] - v[i] * tau[:, None, None]
            dv_i = np.where(use, dv[i], 0.0)
            slack = np.linalg.norm(resid, axis=-1) - delta_y_m - dv_i * tau[:, None]
            need = np.where(use, 2.0 * slack / tau[:, None] ** 2, -np.inf)
            for q in range(Jr):
                drivers[q] = _top(need[:, q], rec, i, tau, n_drivers, drivers[q])
            need_all[:Jr] = np.maximum(need_all[:Jr], need.max(axis=0, initial=-np.inf))
    return need_all, drivers


def fit_acceleration(
    recs: list[Recording],
    a_start: np.ndarray,
    delta_y_m: float,
    horizon_s: float,
    n_drivers: int = 3,
    rel_tol: float = 0.01,
    trusted: list[np.ndarray] | None = None,
) -> tuple[np.ndarray, list[list[Driver]]]:
    """Least a_max per joint (to ``rel_tol``) for R_ACC with estimated velocities.

    A joint is contained iff need(a) <= a. need(a) is not monotone (a larger a_max widens the
    velocity error bound but also shortens the estimator's lag), so the bisection per joint,
    vectorised over joints, finds *a* contained value, not always the least; the calibration
    command verifies containment of the result. ``a_start`` is the lower end (calibration never
    tightens a given set).
    """
    lo = np.asarray(a_start, dtype=float).copy()
    need, drivers = _acc_need(recs, lo, delta_y_m, horizon_s, n_drivers, trusted)
    ok_lo = need <= lo
    hi = np.where(ok_lo, lo, np.maximum(lo * 2.0, need))
    for _ in range(40):  # grow hi until every joint is contained there
        need, _ = _acc_need(recs, hi, delta_y_m, horizon_s, n_drivers, trusted)
        bad = need > hi
        if not bad.any():
            break
        hi = np.where(bad, hi * 2.0, hi)
    while np.any((hi / lo > 1 + rel_tol) & ~ok_lo):
        mid = np.where(ok_lo, lo, np.sqrt(lo * hi))
        need, _ = _acc_need(recs, mid, delta_y_m, horizon_s, n_drivers, trusted)
        good = need <= mid
        hi = np.where(good & ~ok_lo, mid, hi)
        lo = np.where(~good & ~ok_lo, mid, lo)
    _, drivers = _acc_need(recs, hi, delta_y_m, horizon_s, n_drivers, trusted)
    return hi, drivers


def _arm_contained(ps: ParamSet, recs: list[Recording], horizon_s: float) -> bool:
    for rec in recs:
        reach = HumanReach(to_reach_params(ps, rec.kind))
        res = containment(reach, rec.times_s, rec.positions_m, horizon_s, models=("arm",))
        arm_joints = [f"{s}_{j}" for s in "lr" for j in ("shoulder", "elbow", "wrist")]
        if any(j in res["arm"].misses_per_joint for j in arm_joints):
            return False
    return True


def screened(
    base: ParamSet,
    recs: list[Recording],
    dy: float,
    joints: tuple[str, ...],
    rep: CalibrationReport,
) -> list[np.ndarray]:
    """Each recording through a live cell's intake under ``base``: the joint-frames to fit (those
    the gate does not blame for a glitch: bone, frozen, missing; a joint faster than ``base``
    allows is held by the live gate as a jump, but it is motion to fit)."""
    trusted = []
    for rec in recs:
        p = to_reach_params(base.model_copy(update={"delta_y_m": dy}), rec.kind)
        J = rec.positions_m.shape[1]
        s = screen(rec.times_s, rec.positions_m, dy, p.v_max_mps[:J], p.a_max_mps2[:J])
        trusted.append(~s.glitched)
        rep.excluded[rec.name] = [line for line in s.summary(rec.joints)
                                  if not line.startswith(("jump", "beyond"))]  # fmt: skip
        y = rec.positions_m
        chord = np.linalg.norm(y[1:-1] - 0.5 * (y[:-2] + y[2:]), axis=-1).max(axis=0, initial=0)
        for q, jn in enumerate(joints[:J]):
            rep.noise_m[jn] = max(rep.noise_m.get(jn, 0.0), float(chord[q]))
    return trusted


def _monitor_needs(
    base: ParamSet,
    recs: list[Recording],
    dy: float,
    v: np.ndarray,
    a: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """``(J,)`` the largest speed and acceleration the conformance monitor measures on ``recs``
    with the bounds ``v``, ``a`` ``(J,)`` in force (the full-skeleton order; what an upper-body
    recording measures is its joints')."""
    need_v, need_a = np.zeros(len(v)), np.zeros(len(v))
    for rec in recs:
        J = rec.positions_m.shape[1]
        s = screen(rec.times_s, rec.positions_m, dy, v[:J], a[:J])
        need_v[:J] = np.maximum(need_v[:J], s.peak_speed_mps)
        need_a[:J] = np.maximum(need_a[:J], s.peak_acc_mps2)
    return need_v, need_a


def _round_up(x: np.ndarray, margin: float, step: float) -> np.ndarray:
    # Divided by the steps per unit, not multiplied by the step: 531 * 0.01 is
    # 5.3100000000000005, 531 / 100 is 5.31 (what a person reads in the written set).
    return np.ceil(x * margin / step) / round(1.0 / step)


def calibrate(
    base: ParamSet,
    recs: list[Recording],
    horizon_s: float,
    name: str,
    delta_y_m: float | None = None,
) -> tuple[ParamSet, CalibrationReport]:
    """A new parameter set whose bounds contain ``recs`` for the given horizon, with the
    tracker noise bound ``delta_y_m`` (None: ``base``'s). Reconstruction failures are not
    motion: split them off first (:func:`sara_app.human.failures.pieces`).

    Bounds are never lowered below ``base``'s: calibration only widens. The monitor's needs are
    measured with the fitted bounds in force (under them no joint jumps, so the monitor checks
    every joint) and the bounds raised until they cover them.
    """
    # a frame pair within the horizon (what the fits take, ``frame_pairs``) exists where the
    # shortest frame interval is within it
    gaps = [float(np.min(np.diff(r.times_s))) for r in recs if r.n_frames > 1]
    if not (gaps and min(gaps) <= horizon_s + 1e-12):
        raise InputError(
            f"no two frames of the recordings lie within the horizon {horizon_s} s"
            + (f" (their shortest frame interval is {min(gaps):.4g} s)" if gaps else "")
            + ": nothing to fit; give a longer horizon or recordings of more frames"
        )
    kinds = {r.kind for r in recs}
    # with any full-body recording the legs are fitted too (from the full-body ones only)
    joints = skeleton("full" if "full" in kinds else "upper").joints
    dy = base.delta_y_m if delta_y_m is None else float(delta_y_m)
    rep = CalibrationReport(horizon_s, delta_y_m=dy)
    trusted = screened(base, recs, dy, joints, rep)
    v_fit, dvs = fit_velocity(recs, joints, dy, horizon_s, trusted=trusted)
    a_base = np.array([base.joints[j].a_max_mps2 for j in joints])
    v_base = np.array([base.joints[j].v_max_mps for j in joints])
    a_fit, das = fit_acceleration(recs, a_base, dy, horizon_s, trusted=trusted)
    v = np.maximum(v_base, _round_up(v_fit, 1.01, 0.01))
    a = np.maximum(a_base, _round_up(a_fit, 1.0, 1.0))
    for _ in range(8):  # raising a bound only lowers what the monitor finds beyond it
        need_v, need_a = _monitor_needs(base, recs, dy, v, a)
        if (need_v <= v).all() and (need_a <= a).all():
            break
        v = np.maximum(v, _round_up(need_v, 1.01, 0.01))
        a = np.maximum(a, _round_up(need_a, 1.0, 1.0))
    new_joints = dict(base.joints)
    for q, jn in enumerate(joints):
        rep.monitor_v[jn], rep.monitor_a[jn] = float(need_v[q]), float(need_a[q])
        new_joints[jn] = base.joints[jn].model_copy(
            update={"v_max_mps": float(v[q]), "a_max_mps2": float(a[q])}
        )
        rep.v_max[jn], rep.a_max[jn] = float(v[q]), float(a[q])
        rep.drivers_v[jn], rep.drivers_a[jn] = dvs[q], das[q]
    iso_v = max(rep.v_max.values())
    sh_v = max(rep.v_max.get("l_shoulder", 0.0), rep.v_max.get("r_shoulder", 0.0))
    ps = base.model_copy(
        update={
            "name": name,
            "delta_y_m": dy,
            "joints": new_joints,
            "iso_v_max_full_mps": max(base.iso_v_max_full_mps, iso_v),
            "iso_v_max_upper_mps": max(base.iso_v_max_upper_mps, iso_v),
            "arm": base.arm.model_copy(
                update={"shoulder_v_max_mps": max(base.arm.shoulder_v_max_mps, sh_v)}
            ),
        }
    )
    rep.iso_v_max, rep.shoulder_v_max = iso_v, ps.arm.shoulder_v_max_mps
    ps, rep.arm_scale = _fit_arm(ps, recs, horizon_s)
    trusted_only = [p for r, ok in zip(recs, trusted) for p in pieces(r, [
        Failure(a, b - 1, "untrusted") for a, b in runs(np.asarray(~ok.all(axis=1)))])]  # fmt: skip
    ps, rep.combined_raised = _fit_combined(ps, trusted_only, horizon_s)
    for j in rep.combined_raised:
        rep.v_max[j], rep.a_max[j] = ps.joints[j].v_max_mps, ps.joints[j].a_max_mps2
    return ps, rep


def _combined_misses(ps: ParamSet, recs: list[Recording], horizon_s: float) -> set[str]:
    out: set[str] = set()
    for rec in recs:
        reach = HumanReach(to_reach_params(ps, rec.kind))
        res = containment(reach, rec.times_s, rec.positions_m, horizon_s, models=("combined",))
        out |= set(res["combined"].misses_per_joint)
    return out


def _fit_combined(
    ps: ParamSet, recs: list[Recording], horizon_s: float
) -> tuple[ParamSet, dict[str, float]]:
    """Raise the speed and acceleration bounds of the joints the combined model misses (2 % a
    step) until it contains ``recs``. Each bound alone contains them (fitted on displacements);
    the combined model takes both as instantaneous bounds, which a one-frame burst (a heel
    strike) can break. Returns the raised joints' new speed bounds; raises CalibrationError
    if 100 steps (x7) do not close the gap."""
    raised: dict[str, float] = {}
    for _ in range(100):
        missed = _combined_misses(ps, recs, horizon_s)
        if not missed:
            return ps, raised
        joints = dict(ps.joints)
        for j in missed:
            b = joints[j]
            v = float(np.ceil(b.v_max_mps * 102.0) / 100.0)
            a = float(np.ceil(b.a_max_mps2 * 1.02))
            joints[j] = b.model_copy(update={"v_max_mps": v, "a_max_mps2": a})
            raised[j] = v
        ps = ps.model_copy(update={"joints": joints})
    raise ParameterError(
        f"the combined model still misses {sorted(missed)} after raising their bounds 7-fold; "
        "expected calibrated bounds to contain the recordings (a reconstruction failure? "
        "see --max-speed/--max-acc)"
    )


def _scaled_arm(ps: ParamSet, s: float) -> ParamSet:
    a = ps.arm
    return ps.model_copy(
        update={
            "arm": a.model_copy(
                update={
                    "angle_v_max_rad_s": a.angle_v_max_rad_s * s,
                    "angle_a_max_rad_s2": a.angle_a_max_rad_s2 * s,
                    "r_v_max_mps": a.r_v_max_mps * s,
                    "r_a_max_mps2": a.r_a_max_mps2 * s,
                }
            )
        }
    )


def _fit_arm(ps: ParamSet, recs: list[Recording], horizon_s: float) -> tuple[ParamSet, float]:
    """Smallest common scale (>= 1, to 2 %) of the arm model's rate limits that contains recs."""
    if _arm_contained(ps, recs, horizon_s):
        return ps, 1.0
    lo, hi = 1.0, 2.0
    while not _arm_contained(_scaled_arm(ps, hi), recs, horizon_s):
        lo, hi = hi, hi * 2.0
        if hi > 1024:
            return _scaled_arm(ps, hi), hi  # reported: a scale this large means "not fittable"
    while hi / lo > 1.02:
        mid = np.sqrt(lo * hi)
        lo, hi = (lo, mid) if _arm_contained(_scaled_arm(ps, mid), recs, horizon_s) else (mid, hi)
    return _scaled_arm(ps, hi), hi
