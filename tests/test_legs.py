"""The height bound of legs an upper-body tracker does not measure (sara_app.human.legs): the fit
contains what it was fitted to, a recording that breaks it is reported, the shipped bench set's
bound contains the shipped bench recording through the live intake's own bound, the monitor
faults a pelvis that rises too fast only where the bound is used, and `sara-app legs` writes a
set that loads."""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.cell.build import build_cell
from sara_app.cell.intake import rewiden, take_measurement, track_for
from sara_app.errors import InputError
from sara_app.human.intake import Intake
from sara_app.human.legs import PELVIS, containment, fit_legs, leave_one_out, leg_caps
from sara_app.human.params import LEG_PARTS, load_param_set, to_reach_params
from sara_app.human.recording import Recording
from sara_app.human.recordings import PACKAGED_DATA_DIR, load_recording
from sara_app.human.skeleton import FULL_JOINTS, UPPER_JOINTS, skeleton
from sara_app.scenario import Scenario, load_scenario
from sara_app.sim.simulator import SimMetrics, Simulation

BENCH = PACKAGED_DATA_DIR.parent / "cmu62" / "62_07.bvh"
WALK = PACKAGED_DATA_DIR / "02_01.amc"


def _standing(T: int = 240, knee_lift_m: float = 0.0, rise_mps: float = 0.0) -> Recording:
    """A person standing still at 120 Hz (pelvis 1.0 m); the right knee lifted by
    ``knee_lift_m`` in the middle second, the whole body rising at ``rise_mps`` meanwhile."""
    sk = skeleton("full")
    base = {"head": 1.7, "neck": 1.5, "pelvis": 1.0, "shoulder": 1.45, "elbow": 1.2,
            "wrist": 1.0, "hip": 0.92, "knee": 0.5, "ankle": 0.08}  # fmt: skip
    y = np.zeros((T, sk.n_joints, 3))
    for j, name in enumerate(sk.joints):
        side = -0.1 if name.startswith("l_") else 0.1 if name.startswith("r_") else 0.0
        y[:, j] = [side, 0.0, base[name.split("_")[-1]]]
    t = np.arange(T) / 120.0
    mid = (t > 0.5) & (t < 1.5)
    y[mid, sk.joints.index("r_knee"), 2] += knee_lift_m
    y[:, :, 2] += (rise_mps * np.clip(t - 0.5, 0.0, 1.0))[:, None]
    return Recording("standing", "full", t, y)


def test_a_fit_contains_its_recordings_and_takes_the_higher_side() -> None:
    rec = _standing(knee_lift_m=0.3)
    legs = fit_legs([rec])
    # the knee 0.8 m high, the pelvis 1.0 m (the hips' midpoint 0.92 m is lower: measured from)
    assert legs.above_pelvis_m["r_thigh"] == pytest.approx(0.0, abs=1e-9)
    assert legs.above_pelvis_m["l_thigh"] == legs.above_pelvis_m["r_thigh"]  # either side
    assert legs.above_pelvis_m["l_shin"] == legs.above_pelvis_m["r_shin"] == pytest.approx(-0.12)
    assert legs.rise_max_mps == 0.05  # the floor of the rounding: it stands still
    for h in (0.1, 0.5):
        assert containment(rec, legs, h).misses == 0


def test_a_knee_higher_than_fitted_or_a_faster_rise_is_a_miss() -> None:
    legs = fit_legs([_standing()])
    lifted = containment(_standing(knee_lift_m=0.2), legs, 0.2, 0.004)
    assert lifted.misses > 0 and lifted.worst_excess_m == pytest.approx(0.2, abs=0.011)
    assert lifted.unflagged == lifted.misses  # a knee is not measured: nothing flags it
    rising = containment(_standing(rise_mps=0.5), legs, 0.2, 0.004)
    assert 0 < rising.unflagged < rising.misses  # the monitor flags the rise, after a while
    rows = leave_one_out([_standing(), _standing(knee_lift_m=0.2)], (0.1, 0.2))
    assert [r.misses > 0 for r in rows] == [False, False, True, True]


def test_the_check_takes_every_pair_within_the_horizon_brute_force() -> None:
    """On stamps that are not even (denser in one part, a gap in another), the check counts
    exactly the frame pairs within the horizon and their misses: it took spans up to the
    horizon in median frame intervals, which left out the dense part's farther pairs and
    counted pairs across the gap beyond the horizon."""
    from sara_app.human.legs import _leg_tops

    rec = _standing(knee_lift_m=0.25, rise_mps=0.3)
    dt = np.full(rec.n_frames, 1 / 120)
    dt[60:120] = 1 / 240  # denser for a while
    dt[180] = 0.3  # and a gap
    t = np.r_[0.0, np.cumsum(dt[1:])]
    uneven = Recording("uneven", "full", t, rec.positions_m)
    legs = fit_legs([_standing()])
    res = containment(uneven, legs, 0.2)
    tops, zp = _leg_tops(uneven)
    above = np.array([legs.above_pelvis_m[p] for p in LEG_PARTS])
    checked = misses = 0
    for i in range(len(t)):
        for j in range(i + 1, len(t)):
            tau = t[j] - t[i]
            if tau > 0.2 + 1e-12:
                break
            checked += len(LEG_PARTS)
            misses += int((tops[j] > zp[i] + above + legs.rise_max_mps * tau).sum())
    assert (res.checked, res.misses) == (checked, misses) and misses > 0


def test_only_full_body_recordings_fit() -> None:
    rec = _standing()
    upper = Recording("upper", "upper", rec.times_s, rec.positions_m[:, : len(UPPER_JOINTS)])
    with pytest.raises(InputError, match="full-body"):
        fit_legs([upper])
    with pytest.raises(InputError, match="at least one"):
        fit_legs([])


def test_the_bench_sets_bound_contains_the_bench_recording_through_the_live_bound() -> None:
    """Every frame of the shipped bench recording, measured with noise within delta_y: the live
    bound (leg_caps) at 0-0.5 s later lies above every point of each leg part (its joints'
    heights plus its half thickness) then."""
    p = to_reach_params(load_param_set("bench_work"), "full")
    rec = load_recording(BENCH)
    rng = np.random.default_rng(0)
    sk = skeleton("full")
    parts = [sk.parts.index(q) for q in LEG_PARTS]
    joints = sk.part_joints[parts]  # (6, 2)
    y, t = rec.positions_m, rec.times_s
    worst = -np.inf
    for i in rng.choice(len(t) - 60, 400, replace=False):
        meas = y[i] + rng.uniform(-1, 1, y[i].shape) * p.delta_y_m / np.sqrt(3)
        caps = leg_caps(p, meas, 0.0)
        assert caps is not None and np.isinf(caps[[sk.parts.index("head")], 0]).all()
        for k in (1, 12, 24, 60):
            tau = t[i + k] - t[i]
            top = y[i + k][joints, 2].max(axis=1) + p.half_thickness_m[parts]
            worst = max(worst, float((top - (caps[parts, 0] + caps[parts, 1] * tau)).max()))
    assert worst < 0.0


def test_no_bound_without_one_in_the_set() -> None:
    p = to_reach_params(load_param_set("schepp2022_table1"), "full")
    assert leg_caps(p, np.zeros((len(FULL_JOINTS), 3)), 0.0) is None
    bench = to_reach_params(load_param_set("bench_work"), "full")
    y = np.zeros((len(FULL_JOINTS), 3))
    y[PELVIS, 2] = 1.0
    caps = leg_caps(bench, y, np.where(np.arange(len(y)) == PELVIS, 0.05, 0.0))
    assert caps is not None
    wide = leg_caps(bench, y, 0.0)
    assert wide is not None
    thigh = skeleton("full").parts.index("l_thigh")
    assert caps[thigh, 0] == pytest.approx(wide[thigh, 0] + 0.05)  # the pelvis's uncertainty


def test_the_monitor_checks_the_rise_where_the_legs_are_unmeasured_only() -> None:
    """A pelvis rising at 1 m/s (bound 0.6): a fault for an upper-body source, nothing for a
    full-body one, whose legs are measured."""
    p = to_reach_params(load_param_set("bench_work"), "full")
    J = len(FULL_JOINTS)
    rec = _standing(rise_mps=1.0)
    for n_measured, faulted in ((len(UPPER_JOINTS), True), (J, False)):
        intake = Intake(p.delta_y_m, p.v_max_mps, p.a_max_mps2, pelvis_rise_mps=p.pelvis_rise_mps)
        for ti, yi in zip(rec.times_s, rec.positions_m, strict=True):
            intake.take(float(ti), yi, p.delta_y_m, n_measured)
        assert (intake.monitor.counts["rise"] > 0) == faulted
        if faulted:
            assert any(v.quantity == "rise" and v.joint == "pelvis" for v in intake.monitor.last)


def test_the_intake_bounds_unmeasured_legs_and_forgets_the_bound_on_new_parameters() -> None:
    cell = build_cell(load_scenario("bench_handover"))
    track = track_for(cell, "p")
    y = _standing().positions_m[0]
    assert take_measurement(cell, track, 1.0, y, legs_measured=False) is None
    caps = track.state.leg_cap
    assert caps is not None and caps.shape == (cell.shield.reach.skeleton.n_parts, 2)
    assert np.isfinite(caps[:, 0]).sum() == len(LEG_PARTS)
    rewiden(cell, track)
    assert track.state.leg_cap is None  # until the next skeleton: the wider set
    assert take_measurement(cell, track, 1.01, y + 0.001, legs_measured=True) is None
    assert track.state.leg_cap is None  # measured legs need no bound


def test_the_legs_command_writes_a_set_that_loads(tmp_path, capsys) -> None:
    from sara_app.human.report import legs_command

    out = tmp_path / "bench_legs.json"
    ps = legs_command([str(BENCH), str(WALK)], "bench_work", out)
    text = capsys.readouterr().out
    assert "left out" in text and "margin" in text
    loaded = load_param_set(out)
    assert loaded.legs_unmeasured == ps.legs_unmeasured is not None
    assert "ASSUMED" in loaded.sources["legs_unmeasured"]
    for rec in (load_recording(BENCH), load_recording(WALK)):
        assert containment(rec, loaded.legs_unmeasured, 0.5).misses == 0


def test_pieces_of_one_recording_are_left_out_together() -> None:
    """Two pieces of one recording lift the knee alike: left out one by one, each would be
    fitted by its twin and look contained; left out as the recording they come from, both show
    the lift that no other recording has (the misses a new recording of that kind would
    make)."""
    twin_a, twin_b = _standing(knee_lift_m=0.2), _standing(knee_lift_m=0.2)
    other = _standing()
    recs = [twin_a, twin_b, other]
    by_piece = leave_one_out(recs, (0.2,), sources=["a1", "a2", "b"])
    by_source = leave_one_out(recs, (0.2,), sources=["a", "a", "b"])
    assert [r.misses for r in by_piece[:2]] == [0, 0]
    assert all(r.misses > 0 and r.worst_excess_m > 0.19 for r in by_source[:2])
    assert by_source[2].misses == 0
    with pytest.raises(InputError, match="at least 2 recordings"):
        leave_one_out(recs, (0.2,), sources=["a", "a", "a"])
    with pytest.raises(InputError, match="2 sources for 3 recordings"):
        leave_one_out(recs, (0.2,), sources=["a", "b"])


def test_the_legs_command_takes_the_walking_pieces_of_a_recording(tmp_path, capsys) -> None:
    """`NAME@walking`: the walking pieces alone, as `sara-app calibrate` takes them; the fitted
    bound contains each piece, and the set's source names the pieces' recording as given."""
    from sara_app.human.report import legs_command
    from sara_app.human.segments import walking_pieces

    out = tmp_path / "walk_legs.json"
    ps = legs_command([f"{WALK}@walking", str(BENCH)], "work", out)
    text = capsys.readouterr().out
    walk = load_recording(WALK)
    pieces = walking_pieces(walk)
    assert pieces and f"{walk.name}: walking pieces" in text
    assert ps.legs_unmeasured is not None
    assert f"{WALK}@walking" in ps.sources["legs_unmeasured"]
    for rec in pieces:
        assert containment(rec, ps.legs_unmeasured, 0.5).misses == 0


def _handover_upper(mode: str, bounded: bool) -> SimMetrics:
    """The shipped upper-body handover in ``mode``, its set with or without the legs' bound,
    run for the scenario's duration or until the goal."""
    sc = load_scenario("bench_handover_upper")
    d = sc.model_dump()
    d["shield"]["mode"] = mode
    if not bounded:
        ps = load_param_set("bench_work").model_dump()
        ps["legs_unmeasured"] = None
        d["human_params"] = ps
    sim = Simulation(Scenario.model_validate(d))
    for _ in range(int(round(sc.sim.duration_s / sim.dt))):
        sim.step()
        if sim.time_to_goal_s is not None:
            break
    return sim.metrics()


def test_the_bound_lets_the_robot_work_beside_an_upper_body_track_without_a_collision() -> None:
    """The handover tracked upper-body: with the legs' bound SSM and PFL reach the goal with no
    collision while moving and no harmful contact; without it the unmeasured legs' reach holds
    SSM on its failsafe far more often and it does not reach the goal in the scenario's time."""
    ssm, pfl = _handover_upper("ssm", True), _handover_upper("pfl", True)
    for m in (ssm, pfl):
        assert m.time_to_goal_s is not None, m.lines()
        assert m.collisions_moving == 0 and m.harmful_contacts == 0 and m.fault_cycles == 0
    unbounded = _handover_upper("ssm", False)
    assert unbounded.collisions_moving == 0
    assert unbounded.time_to_goal_s is None and unbounded.failsafe_share > 2 * ssm.failsafe_share


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda b: b["above_pelvis_m"].pop("l_foot"), "missing"),
        (lambda b: b["above_pelvis_m"].update(l_hand=0.0), "l_hand"),
        (lambda b: b["above_pelvis_m"].update(l_shin=5.0), "l_shin"),
        (lambda b: b["above_pelvis_m"].update(l_shin=float("nan")), "l_shin"),
        (lambda b: b.update(rise_max_mps=0.0), "rise_max_mps"),
        (lambda b: b.update(rise_max_mps=float("inf")), "rise_max_mps"),
    ],
)
def test_a_malformed_bound_is_refused_naming_it(change, message: str) -> None:
    """A parameter set whose legs' bound misses a leg part, names another part, or holds an
    out-of-range or non-finite height or rise is refused at the boundary, naming what is wrong."""
    from sara_app.errors import ParameterError
    from sara_app.human.params import parse_param_set

    data = load_param_set("bench_work").model_dump()
    change(data["legs_unmeasured"])
    with pytest.raises(ParameterError, match=message):
        parse_param_set(data)
