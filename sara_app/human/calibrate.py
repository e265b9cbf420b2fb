"""Fit per-joint bounds from recordings so that the models contain them.

For every recording, every frame i as a measurement and every later frame j within the horizon
(tau = t_j - t_i), a joint's displacement must fit the model:

- R_VEL / ISO 13855 / R_POS roots: |y_j - y_i| <= delta_y + v_max tau, so the least sound
  v_max is max (|y_j - y_i| - delta_y) / tau;
- R_ACC: |y_j - y_i - v_hat_i tau| <= delta_y + dv_i tau + a_max tau^2 / 2, where the velocity
  error bound dv_i itself grows with a_max (``velocity.py``): a fixed-point iteration on a_max;
- the arm model: its four rate limits are scaled together (bisection) until every arm joint is
  contained, its shoulder speed is the shoulders' v_max.

Nothing is dropped: each bound comes with the frames that drive it (recording, time, horizon,
value), so a one-frame tracking glitch shows up in the report and a person judges it.
Recordings are taken as ground truth with zero latency (the delay is a property of the sensor
in the cell; the fitted bounds hold for motion, whatever delay is added later).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sara_app.human.analysis import containment
from sara_app.human.params import ParamSet, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.recordings import Recording
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


def _pairs(rec: Recording, horizon_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Frame index pairs ``(i, j)`` with 0 < t_j - t_i <= horizon, and their tau."""
    t = rec.times_s
    n = int(np.searchsorted(t - t[0], horizon_s, side="right"))
    i, k = np.meshgrid(np.arange(len(t)), np.arange(1, max(n, 2)), indexing="ij")
    j = i + k
    ok = j < len(t)
    i, j = i[ok], j[ok]
    tau = t[j] - t[i]
    keep = tau <= horizon_s + 1e-12
    return i[keep], j[keep], tau[keep]


def _top(values: np.ndarray, rec: Recording, i: np.ndarray, tau: np.ndarray, n: int) -> list:
    order = np.argsort(values)[::-1][:n]
    return [
        Driver(rec.name, float(rec.times_s[i[o]]), float(tau[o]), float(values[o])) for o in order
    ]


def fit_velocity(
    recs: list[Recording],
    joints: tuple[str, ...],
    delta_y_m: float,
    horizon_s: float,
    n_drivers: int = 3,
) -> tuple[np.ndarray, list[list[Driver]]]:
    """Least v_max per joint ``(J,)`` that contains every displacement, and its drivers."""
    best = np.zeros(len(joints))
    drivers: list[list[Driver]] = [[] for _ in joints]
    for rec in recs:
        i, j, tau = _pairs(rec, horizon_s)
        disp = np.linalg.norm(rec.positions_m[j] - rec.positions_m[i], axis=-1)  # (N, J)
        need = (disp - delta_y_m) / tau[:, None]
        for q in range(len(joints)):
            drivers[q] += _top(need[:, q], rec, i, tau, n_drivers)
        best = np.maximum(best, need.max(axis=0))
    for q in range(len(joints)):
        drivers[q] = sorted(drivers[q], key=lambda d: -d.value)[:n_drivers]
    return best, drivers


def _acc_need(
    recs: list[Recording], a: np.ndarray, delta_y_m: float, horizon_s: float, n_drivers: int
) -> tuple[np.ndarray, list[list[Driver]]]:
    """Largest a_max the data need per joint when velocities are estimated with ``a``."""
    J = a.shape[0]
    need_all = np.full(J, -np.inf)
    drivers: list[list[Driver]] = [[] for _ in range(J)]
    for rec in recs:
        v, dv = estimate_recording(rec.times_s, rec.positions_m, delta_y_m, a)
        i, j, tau = _pairs(rec, horizon_s)
        ok = np.isfinite(dv[i]).all(axis=1)
        i, j, tau = i[ok], j[ok], tau[ok]
        resid = rec.positions_m[j] - rec.positions_m[i] - v[i] * tau[:, None, None]
        slack = np.linalg.norm(resid, axis=-1) - delta_y_m - dv[i] * tau[:, None]
        need = 2.0 * slack / tau[:, None] ** 2
        for q in range(J):
            drivers[q] += _top(need[:, q], rec, i, tau, n_drivers)
        need_all = np.maximum(need_all, need.max(axis=0))
    return need_all, [sorted(d, key=lambda x: -x.value)[:n_drivers] for d in drivers]


def fit_acceleration(
    recs: list[Recording],
    a_start: np.ndarray,
    delta_y_m: float,
    horizon_s: float,
    n_drivers: int = 3,
    rel_tol: float = 0.01,
) -> tuple[np.ndarray, list[list[Driver]]]:
    """Least a_max per joint (to ``rel_tol``) for R_ACC with estimated velocities.

    A joint is contained iff need(a) <= a. need(a) is not monotone (a larger a_max widens the
    velocity error bound but also shortens the estimator's lag), so the bisection per joint,
    vectorised over joints, finds *a* contained value, not always the least; the calibration
    command verifies containment of the result. ``a_start`` is the lower end (calibration never
    tightens a given set).
    """
    lo = np.asarray(a_start, dtype=float).copy()
    need, drivers = _acc_need(recs, lo, delta_y_m, horizon_s, n_drivers)
    ok_lo = need <= lo
    hi = np.where(ok_lo, lo, np.maximum(lo * 2.0, need))
    for _ in range(40):  # grow hi until every joint is contained there
        need, _ = _acc_need(recs, hi, delta_y_m, horizon_s, n_drivers)
        bad = need > hi
        if not bad.any():
            break
        hi = np.where(bad, hi * 2.0, hi)
    while np.any((hi / lo > 1 + rel_tol) & ~ok_lo):
        mid = np.where(ok_lo, lo, np.sqrt(lo * hi))
        need, _ = _acc_need(recs, mid, delta_y_m, horizon_s, n_drivers)
        good = need <= mid
        hi = np.where(good & ~ok_lo, mid, hi)
        lo = np.where(~good & ~ok_lo, mid, lo)
    _, drivers = _acc_need(recs, hi, delta_y_m, horizon_s, n_drivers)
    return hi, drivers


def _arm_contained(ps: ParamSet, recs: list[Recording], horizon_s: float) -> bool:
    for rec in recs:
        reach = HumanReach(to_reach_params(ps, rec.kind))
        res = containment(reach, rec.times_s, rec.positions_m, horizon_s, models=("arm",))
        arm_joints = [f"{s}_{j}" for s in "lr" for j in ("shoulder", "elbow", "wrist")]
        if any(j in res["arm"].misses_per_joint for j in arm_joints):
            return False
    return True


def calibrate(
    base: ParamSet, recs: list[Recording], horizon_s: float, name: str
) -> tuple[ParamSet, CalibrationReport]:
    """A new parameter set whose bounds contain ``recs`` for the given horizon.

    Bounds are never lowered below ``base``'s: calibration only widens.
    """
    kinds = {r.kind for r in recs}
    joints = skeleton("full" if kinds == {"full"} else "upper").joints
    dy = base.delta_y_m
    rep = CalibrationReport(horizon_s)
    v_fit, dvs = fit_velocity(recs, joints, dy, horizon_s)
    a0 = np.array([base.joints[j].a_max_mps2 for j in joints])
    a_fit, das = fit_acceleration(recs, a0, dy, horizon_s)
    new_joints = dict(base.joints)
    for q, jn in enumerate(joints):
        v = max(base.joints[jn].v_max_mps, float(np.ceil(v_fit[q] * 1.01 * 100) / 100))
        a = max(base.joints[jn].a_max_mps2, float(np.ceil(a_fit[q])))
        new_joints[jn] = base.joints[jn].model_copy(update={"v_max_mps": v, "a_max_mps2": a})
        rep.v_max[jn], rep.a_max[jn] = v, a
        rep.drivers_v[jn], rep.drivers_a[jn] = dvs[q], das[q]
    iso_v = max(rep.v_max.values())
    sh_v = max(rep.v_max.get("l_shoulder", 0.0), rep.v_max.get("r_shoulder", 0.0))
    ps = base.model_copy(
        update={
            "name": name,
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
    return ps, rep


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
