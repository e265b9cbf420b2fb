"""Offline analysis commands on recordings: capsules to JSONL, containment, volumes, calibration.

Printing and file formats live here; the measurements are in ``analysis.py`` and
``calibrate.py``.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TextIO

import numpy as np

from sara_app.errors import InputError
from sara_app.human.analysis import (
    EFFECTIVE,
    Containment,
    containment,
    mean_volume,
    occupancies,
)
from sara_app.human.calibrate import CalibrationReport, calibrate
from sara_app.human.displacement import Shaping
from sara_app.human.failures import Ceilings, describe, split
from sara_app.human.intake import screen_recording
from sara_app.human.params import ParamSet, load_param_set, save_param_set, to_reach_params
from sara_app.human.reach import MODELS, HumanReach
from sara_app.human.recordings import Recording, load_recording, require_frames
from sara_app.human.segments import MIN_DURATION_S, MIN_SPEED_MPS, walking_pieces
from sara_app.human.sound_record import MARGIN_KEYS
from sara_app.human.validation import (
    Validation,
    containment_on,
    format_validation,
    leave_one_out,
    widened,
)


def write_jsonl(
    reach: HumanReach,
    rec: Recording,
    horizon_s: float,
    out: TextIO,
    models: Sequence[str] = MODELS,
) -> int:
    """One JSON line per frame and model: the capsules for [0, horizon] after that frame.

    ``{"frame": i, "t_s": t, "model": m, "horizon_s": h, "params": name, "available": bool,
    "capsules": [{"part": name, "p1": [x, y, z], "p2": [x, y, z], "radius": r}, ...]}`` (metres,
    world frame); a model without a set at that frame (no velocity estimate yet) is
    ``"available": false`` with no capsules. Returns the number of lines written.
    """
    occ = occupancies(
        reach, rec.times_s, rec.positions_m, np.zeros(1), np.array([horizon_s]), tuple(models)
    )
    n = 0
    for i in range(rec.n_frames):
        for m in models:
            o = occ[m]
            available = bool(np.isfinite(o.radius[i, 0]).all())
            caps = [
                {
                    "part": name,
                    "p1": np.round(o.ends[i, 0, c, 0], 6).tolist(),
                    "p2": np.round(o.ends[i, 0, c, 1], 6).tolist(),
                    "radius": round(float(o.radius[i, 0, c]), 6),
                }
                for c, name in enumerate(o.names)
                if available
            ]
            line = {
                "frame": i,
                "t_s": round(float(rec.times_s[i]), 6),
                "model": m,
                "horizon_s": horizon_s,
                "params": reach.params.name,
                "available": available,
                "capsules": caps,
            }
            out.write(json.dumps(line) + "\n")
            n += 1
    return n


def in_use(models: Sequence[str]) -> tuple[str, ...]:
    """Of ``models``, those a cell verifies with by default (``shield.models``): the effective
    set is theirs; all of ``models`` when none of them is."""
    from sara_app.safety.settings import ShieldSettings

    used = tuple(m for m in ShieldSettings().models if m in models)
    return used or tuple(models)


def _check_horizon(horizon_s: float) -> None:
    """Refuse (:class:`InputError`) a horizon that is not a finite number of seconds > 0."""
    if not (np.isfinite(horizon_s) and horizon_s > 0):
        raise InputError(f"horizon {horizon_s} s; expected a finite value > 0")


def _excess(excess_m: float) -> str:
    """A miss's distance outside the set, in words."""
    if not np.isfinite(excess_m):
        return "more than any finite distance (coordinates beyond what floats can square)"
    return f"{100 * excess_m:.1f} cm" if excess_m < 10.0 else f"{excess_m:.3g} m"


def format_containment(name: str, res: dict[str, Containment]) -> str:
    lines = [f"containment on {name} (share of future joint positions inside the set; "
             "effective: inside every model a cell uses, what the verdict relies on):"]  # fmt: skip
    for m, c in res.items():
        na = f"; unavailable for {c.unavailable} (no velocity estimate)" if c.unavailable else ""
        if c.unflagged is not None:
            misses = c.checked - c.contained
            na += (f"; {c.unflagged} unflagged (the monitor had not faulted the person), "
                   f"{misses - c.unflagged} at a fault")  # fmt: skip
        if not c.checked:  # a share of nothing is no containment
            lines.append(f"  {m:9s} nothing checked: no future position within the horizon{na}")
            continue
        lines.append(f"  {m:9s} {100 * c.share:8.3f} %  ({c.checked - c.contained} misses{na})")
        if c.misses_per_joint:
            worst = ", ".join(
                f"{w.joint} at t={w.t_s:.3f}s +{w.dt_s:.3f}s by " + _excess(w.excess_m)
                for w in c.worst[:3]
            )
            per = ", ".join(f"{j}: {n}" for j, n in c.misses_per_joint.items())
            lines.append(f"            misses per joint: {per}")
            lines.append(f"            worst: {worst}")
    return "\n".join(lines)


Load = Callable[[str], Recording]
"""How a command reads a recording by path or name (:func:`load_recording` with the user's
options)."""


WALKING_SUFFIX = "@walking"
"""A recording named ``<name>@walking``: its walking pieces alone (``sara-app calibrate``)."""


def walking_or_whole(rec: Recording, walking: bool) -> list[Recording]:
    """``rec`` itself, or with ``walking`` its walking pieces (:mod:`sara_app.human.segments`;
    printed, and an empty list said to be left out)."""
    if not walking:
        return [rec]
    found = walking_pieces(rec)
    spans = ", ".join(p.name.split("@")[1] for p in found)
    print(f"  {rec.name}: walking pieces {spans or 'none: left out'}")
    return found


def reach_command(
    recording: str,
    horizon_s: float,
    params: str,
    out: Path | None,
    models: Sequence[str],
    load: Load = load_recording,
) -> dict[str, Containment]:
    _check_horizon(horizon_s)
    rec = require_frames(load(recording))
    ps = load_param_set(params)
    reach = HumanReach(to_reach_params(ps, rec.kind))
    # every input error comes before anything is written
    s = screen_recording(reach.params, rec)
    res = containment(reach, rec.times_s, rec.positions_m, horizon_s, tuple(models),
                      faulted=s.faulted, effective_of=in_use(models))  # fmt: skip
    if out is not None:
        with open(out, "w") as f:
            n = write_jsonl(reach, rec, horizon_s, f, models)
        print(f"wrote {n} lines to {out}")
    print(f"{rec.name}: {rec.n_frames} frames, parameters {ps.name!r}, horizon {horizon_s} s")
    flagged = s.summary(rec.joints)
    print("tracking gate and conformance monitor (as a live cell would see it): "
          + ("nothing flagged" if not flagged else ""))  # fmt: skip
    for line in flagged:
        print(f"  {line}")
    print(format_containment(rec.name, res))
    vols = mean_volume(reach, rec.times_s, rec.positions_m, horizon_s, tuple(models))
    print("mean set volume over [0, horizon] (Monte Carlo, 20 frames):")
    for m, v in vols.items():
        print(f"  {m:9s} {v:8.4f} m^3")
    return res


def volume_table(
    recording: str,
    params: str,
    horizons: Sequence[float],
    png: Path | None,
    models: Sequence[str] = MODELS,
    load: Load = load_recording,
) -> dict[str, list[float]]:
    """Mean set volume per model and horizon (the trend of Schepp et al. 2022 Fig. 7), optional
    PNG."""
    rec = require_frames(load(recording))
    ps = load_param_set(params)
    reach = HumanReach(to_reach_params(ps, rec.kind))
    columns = [*models, EFFECTIVE] if len(models) > 1 else list(models)
    table: dict[str, list[float]] = {m: [] for m in columns}
    for h in horizons:
        v = mean_volume(reach, rec.times_s, rec.positions_m, h, tuple(models))
        for m in columns:
            table[m].append(v[m])
    print(f"mean set volume [m^3] on {rec.name}, parameters {ps.name!r}")
    print("horizon_s " + " ".join(f"{m:>9s}" for m in columns))
    for k, h in enumerate(horizons):
        print(f"{h:9.3f} " + " ".join(f"{table[m][k]:9.4f}" for m in columns))
    if png is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 4))
        for m in columns:
            ax.plot(horizons, table[m], marker="o", label=m)
        ax.set_xlabel("horizon t_f [s]")
        ax.set_ylabel("mean reachable-set volume [m$^3$]")
        ax.set_title(f"{rec.name}: set volume vs. horizon ({ps.name})")
        ax.set_yscale("log")
        ax.grid(True, alpha=0.3, which="both")
        ax.legend()
        fig.tight_layout()
        fig.savefig(png, dpi=120)
        print(f"wrote {png}")
    return table


def format_calibration(rep: CalibrationReport) -> str:
    lines = [f"tracker noise bound delta_y {1e3 * rep.delta_y_m:.1f} mm; largest one-frame chord "
             "deviation per joint (noise alone stays below 2 delta_y):"]  # fmt: skip
    lines.append("  " + ", ".join(f"{j} {1e3 * d:.1f} mm" for j, d in rep.noise_m.items()))
    for name, flagged in rep.excluded.items():
        what = "; ".join(flagged) if flagged else "flagged nothing (no frame left out)"
        lines.append(f"  {name}: tracking gate {what}")
    lines.append(f"calibrated bounds (horizon {rep.horizon_s} s) and the frames that drive them:")
    for j in rep.v_max:
        dv = rep.drivers_v[j][0] if rep.drivers_v[j] else None
        da = rep.drivers_a[j][0] if rep.drivers_a[j] else None
        line = f"  {j:11s} v_max {rep.v_max[j]:6.2f} m/s  a_max {rep.a_max[j]:7.1f} m/s^2"
        if dv:
            line += f" | v by {dv.recording} t={dv.t_s:.3f}s +{dv.tau_s:.3f}s ({dv.value:.2f})"
        if da:
            line += f" | a by {da.recording} t={da.t_s:.3f}s +{da.tau_s:.3f}s ({da.value:.1f})"
        if j in rep.monitor_v:
            line += f" | monitor needs {rep.monitor_v[j]:.2f} m/s, {rep.monitor_a[j]:.1f} m/s^2"
        lines.append(line)
    if rep.combined_raised:
        lines.append("  raised until the combined model contains them: " + ", ".join(
            f"{j} v_max {v:.2f} m/s, a_max {rep.a_max[j]:.0f} m/s^2"
            for j, v in rep.combined_raised.items()))  # fmt: skip
    lines.append(f"  ISO 13855 speed needed: {rep.iso_v_max:.2f} m/s")
    lines.append(
        f"  arm model: shoulder speed {rep.shoulder_v_max:.2f} m/s, "
        f"rate limits x{rep.arm_scale:.2f}"
    )
    return "\n".join(lines)


def _description(
    recs: Sequence[Recording], walk: Sequence[bool], walking: bool, horizon_s: float, base: str,
    val: Validation | None, widen: bool = True,
) -> str:  # fmt: skip
    """How a calibrated set was fitted, for its ``description``."""
    on = ", ".join(r.name + (WALKING_SUFFIX if w and not walking else "")
                   for r, w in zip(recs, walk))  # fmt: skip
    if walking or any(walk):
        which = "their" if walking else "@walking:"
        on += (f" ({which} walking pieces, the pelvis over the floor at {MIN_SPEED_MPS:g} m/s or "
               f"more for {MIN_DURATION_S:g} s or more)")  # fmt: skip
    margin = ""
    if val is not None:
        factors = "speeds x{:.3f}, accelerations x{:.3f}, arm rates x{:.3f}".format(*val.margin)
        margin = (
            f", then by the margin that leaving each recording out derives ({factors})"
            if widen
            else f", not widened by the margin that leaving each recording out derives ({factors}):"
            " declined, so on a recording it was not fitted to it is as sound as its left-out"
            " rows say"
        )
    return (f"Calibrated by `sara-app calibrate` on {on} (horizon {horizon_s} s) from {base!r}: "
            f"bounds widened until the models contain the recordings{margin}. Bounds driven by "
            "single frames are listed by the command.")  # fmt: skip


def _fit_pieces(
    recordings: Sequence[str], load: Load, ceilings: Ceilings | None, delta_y_m: float,
    walking: bool = False,
) -> tuple[list[Recording], list[bool], list[list[Recording]], list[str]]:  # fmt: skip
    """The recordings to fit, whether each is taken by its walking pieces, and each one's
    pieces: its walking pieces (with ``walking``, or named ``<name>@walking``) or itself,
    reconstruction failures under ``ceilings`` split off; a recording without a walking piece
    is left out (and said so). Also the failures' lines."""
    walk = [walking or r.endswith(WALKING_SUFFIX) for r in recordings]
    recs = [require_frames(load(r.removesuffix(WALKING_SUFFIX))) for r in recordings]
    walks = [walking_or_whole(r, w) for r, w in zip(recs, walk)]
    keep = [i for i, pieces_ in enumerate(walks) if pieces_]
    recs, walks, walk = [recs[i] for i in keep], [walks[i] for i in keep], [walk[i] for i in keep]
    splits = [[split(p, ceilings, delta_y_m) for p in w] for w in walks]
    kept = [[q for pieces_, _ in sp for q in pieces_] for sp in splits]
    failed = [line for w, sp in zip(walks, splits) for p, (_, f) in zip(w, sp)
              for line in describe(p, f)]  # fmt: skip
    return recs, walk, kept, failed


def _print_failures(ceilings: Ceilings | None, failed: list[str]) -> None:
    """The reconstruction failures left out under ``ceilings`` (nothing without ceilings)."""
    if ceilings is not None:
        print(f"reconstruction failures left out (ceilings {ceilings.max_speed_mps:g} m/s, "
              f"{ceilings.max_acc_mps2:g} m/s^2): {len(failed) or 'none'}")  # fmt: skip
        print("\n".join(f"  {line}" for line in failed))


def calibrate_command(
    recordings: Sequence[str],
    horizon_s: float,
    base: str,
    name: str,
    out: Path,
    delta_y_m: float | None = None,
    validate: bool = False,
    load: Load = load_recording,
    ceilings: Ceilings | None = None,
    walking: bool = False,
    widen: bool = True,
) -> tuple[ParamSet, CalibrationReport]:
    """Calibrate ``base`` on ``recordings`` and write the set to ``out``. With ``walking``, on
    their walking pieces only (:mod:`sara_app.human.segments`; a recording without any is left
    out, and said so), as for each recording named ``<name>@walking``; with ``ceilings``,
    reconstruction failures are split off first and listed (:mod:`sara_app.human.failures`);
    with ``validate``, first leave each recording out in turn (:mod:`sara_app.human.validation`)
    and widen the written set by the margin that derives; without ``widen``, that margin is
    recorded as declined and the set stays as fitted (its left-out rows say what that costs)."""
    _check_horizon(horizon_s)
    if delta_y_m is not None and not (np.isfinite(delta_y_m) and delta_y_m >= 0):
        raise InputError(f"tracker noise bound {delta_y_m} m; expected a finite value >= 0")
    if not widen and not validate:  # before minutes of reading recordings
        raise InputError("--no-widen declines the margin --leave-one-out derives: give both, or "
                         "neither (calibrate alone widens nothing)")  # fmt: skip
    b = load_param_set(base)
    dy = b.delta_y_m if delta_y_m is None else delta_y_m
    recs, walk, kept, failed = _fit_pieces(recordings, load, ceilings, dy, walking)
    if not recs:
        raise InputError("none of the recordings has a walking piece to calibrate on")
    if validate and len(recs) < 2:
        raise InputError("leave-one-out validation needs at least two recordings")
    ps, rep = calibrate(b, [p for ps_ in kept for p in ps_], horizon_s, name, delta_y_m)
    print(format_calibration(rep))
    _print_failures(ceilings, failed)
    val = None
    if validate:
        val, _ = leave_one_out(b, kept, [r.name for r in recs], horizon_s, in_use(MODELS),
                               delta_y_m)  # fmt: skip
        print(format_validation(val))
        if widen:
            ps = widened(ps, val.margin, name)
    summary = {}
    checked = dict.fromkeys(MODELS, 0)
    for rec, pieces in zip(recs, kept):
        for label, pset in (("base", b), ("calibrated", ps)):
            res = containment_on(pset, pieces, horizon_s, MODELS, in_use(MODELS)).counts
            misses = {m: c[0] - c[1] for m, c in res.items()}
            print(f"  {rec.name} with {label} set: " + ", ".join(
                (f"{m} {100 * c[1] / c[0]:.4f}% ({misses[m]} misses" if c[0] else
                 f"{m} nothing checked ({misses[m]} misses")
                + ("" if m != EFFECTIVE else f", {c[2]} unflagged") + ")"
                for m, c in res.items()
            ))  # fmt: skip
            if label == "calibrated":
                summary[rec.name] = misses
                for m in MODELS:
                    checked[m] += res[m][0]
    # a model is sound on the recordings where it missed nothing it was checked on, and it was
    # checked on something (an acceleration model is unavailable on two frames)
    sound = [m for m in MODELS if checked[m] and all(s[m] == 0 for s in summary.values())]
    # The hand ball is centred at the wrist: its radius must reach the fingertips (Pereira & Althoff
    # 2016's hand radius 0.205 m), which Schepp et al. 2022's 0.205 m thickness does not.
    parts = dict(ps.body_parts)
    for hand in ("l_hand", "r_hand"):
        parts[hand] = parts[hand].model_copy(
            update={"thickness_m": max(parts[hand].thickness_m, 0.41)}
        )
    ps = ps.model_copy(
        update={
            "body_parts": parts,
            "description": _description(recs, walk, walking, horizon_s, base, val, widen),
            "sound_for": {
                "models": ", ".join(sound),
                "misses_per_recording": json.dumps(summary),
                "horizon_s": str(horizon_s),
                **(
                    {}
                    if ceilings is None
                    else {
                        "ceilings": f"{ceilings.max_speed_mps:g} m/s, "
                        f"{ceilings.max_acc_mps2:g} m/s^2 (one frame, beyond the noise)",
                        "reconstruction_failures_left_out": "; ".join(failed) or "none",
                    }
                ),
                **(
                    {}
                    if val is None
                    else {
                        "leave_one_out": json.dumps(
                            {
                                r.recording: {
                                    "share": round(r.share, 6),
                                    "misses": r.checked - r.contained,
                                    "unflagged": r.unflagged,
                                }
                                for r in val.rows
                            }
                        ),
                        MARGIN_KEYS[widen]: ", ".join(f"{m:.3f}" for m in val.margin),
                    }
                ),
            },
        }
    )
    save_param_set(ps, out)
    print(f"wrote parameter set {name!r} to {out}; models sound on these recordings: {sound}")
    return ps, rep


def legs_command(
    recordings: Sequence[str], params: str, out: Path, load: Load = load_recording
) -> ParamSet:
    """``sara-app legs``: the height bound of unmeasured legs (:mod:`sara_app.human.legs`)
    fitted to full-body ``recordings`` with the margin their leave-one-out validation needs,
    added to the set ``params`` and written to ``out``; prints the validation. A recording
    named ``<name>@walking`` gives its walking pieces alone (as for ``sara-app calibrate``;
    none: left out, and said so); pieces of one recording are left out together."""
    from sara_app.human.legs import containment, fit_validated, format_containment

    recs, sources = [], []
    for name in recordings:
        given = name.removesuffix(WALKING_SUFFIX)  # as given: two files may share a name
        rec = require_frames(load(given))
        parts = walking_or_whole(rec, name.endswith(WALKING_SUFFIX))
        recs += parts
        sources += [given] * len(parts)
    if not recs:
        raise InputError("none of the recordings has a piece to fit the legs' heights to")
    base = load_param_set(params)
    bounded, rows, margin_m = fit_validated(recs, delta_y_m=base.delta_y_m, sources=sources)
    print("legs below the pelvis, each recording left out (no margin):")
    print(f"{format_containment(rows)}\nmargin from the worst excess: {margin_m:.2f} m")
    fitted = [containment(r, bounded, h, base.delta_y_m) for r in recs for h in (0.1, 0.2, 0.5)]
    print(f"the bound with the margin, on every recording:\n{format_containment(fitted)}")
    print(f"bound: {bounded.model_dump()}")
    held_out = {r.recording: [r.misses, r.unflagged] for r in rows if r.horizon_s == 0.5}
    ps = base.model_copy(
        update={
            "legs_unmeasured": bounded,
            "sources": {
                **base.sources,
                "legs_unmeasured": (
                    f"`sara-app legs` on {', '.join(recordings)}: each leg part's "
                    f"highest joint over the pelvis and the pelvis's fastest rise (0.5 s), plus "
                    f"the margin {margin_m:.2f} m that leaving each recording out needs. ASSUMED "
                    "for the activity: feet on the floor (no kneeling on the bench, climbing or "
                    "kicking); the rise is monitored"
                ),
            },
            "sound_for": {
                **base.sound_for,
                "legs_unmeasured_left_out_misses_unflagged_0_5s": json.dumps(held_out),
            },
        }
    )
    save_param_set(ps, out)
    print(f"wrote {out}")
    return ps


def displacement_command(
    recordings: Sequence[str],
    params: str,
    out: Path,
    load: Load = load_recording,
    ceilings: Ceilings | None = None,
    shaping: Shaping | None = None,
) -> ParamSet:
    """``sara-app displacement``: R_VEL's displacement bound (:mod:`sara_app.human.displacement`)
    fitted to ``recordings`` (reconstruction failures under ``ceilings`` split off, the frames
    the tracking gate distrusts under ``params`` left out), each recording first left out in
    turn and checked against ``params`` with the others' table (printed), then fitted on all,
    shaped by ``shaping`` (default: the upper body, at least ISO 13855's 2 m/s sustained), added
    to the set ``params`` and written to ``out``. A recording named
    ``<name>@walking`` gives its walking pieces alone."""
    from sara_app.human.calibrate import screened
    from sara_app.human.displacement import (
        STEP_S,
        fit_displacement,
        format_held_out,
        leave_one_out,
        to_bound,
        with_bound,
    )
    from sara_app.human.skeleton import FULL_JOINTS

    shaping = shaping or Shaping()
    base = load_param_set(params)
    dy = base.delta_y_m
    recs, _, kept, failed = _fit_pieces(recordings, load, ceilings, dy)
    _print_failures(ceilings, failed)
    names = [r.name for r, k in zip(recs, kept) if k]
    pieces = [k for k in kept if k]
    if not pieces:
        raise InputError("none of the recordings has a piece to fit a displacement bound to")
    trusted = [screened(base, k, dy, FULL_JOINTS, CalibrationReport(0.5)) for k in pieces]
    rows = leave_one_out(base, pieces, trusted, names, shaping=shaping) if len(pieces) > 1 else []
    if rows:
        print(f"each recording left out (set {base.name!r} with the others' table; effective "
              f"set of acc, vel, pos, combined):\n{format_held_out(rows)}")  # fmt: skip
    flat = [p for ps in pieces for p in ps]
    table = fit_displacement(flat, dy, 0.5, STEP_S, [t for ts in trusted for t in ts])
    bound = to_bound(table, STEP_S, base, shaping)
    for j in ("head", "l_wrist", "r_wrist", "pelvis", "r_ankle"):
        row = bound.max_m[j]
        print(f"  {j}: " + ", ".join(f"{(i + 1) * STEP_S:g} s {row[i]:.3f} m"
                                    for i in (4, 9, 19, 49) if i < len(row)))  # fmt: skip
    held_out = {r.recording: {f"{h:g}s": [k - n, u] for h, (k, n, u) in r.by_horizon.items()}
                for r in rows}  # fmt: skip
    ps = with_bound(base, bound).model_copy(
        update={
            "sources": {
                **base.sources,
                "displacement": (
                    f"`sara-app displacement` on {', '.join(recordings)}: per joint the largest "
                    f"distance between positions tau apart (beyond delta_y), cells of {STEP_S:g} s "
                    f"to 0.5 s, non-decreasing, times {shaping.margin:g}, at least "
                    f"{shaping.floor_mps:g} m/s x tau (ISO 13855's approach speed), for "
                    f"{', '.join(shaping.joints)} (other joints: v_max x tau)"
                ),
            },
            "sound_for": {
                **base.sound_for,
                "displacement_left_out_misses_unflagged": json.dumps(held_out),
            },
        }
    )
    save_param_set(ps, out)
    print(f"wrote {out}")
    return ps
