"""Containment of real motion (CMU walk, run, boxing) per model and parameter set.

The paper's Table I set is sound for the walk only where the walk respects its bounds; the
failures on the fast clips are the finding of Pereira & Althoff 2016 Sec. III-B and are asserted as
such (a model that suddenly contained the boxing hands with 2 m/s would mean a broken measurement).
The shipped calibrated set contains all three clips with every model.
"""

from __future__ import annotations

import pytest

from sara_app.errors import RecordingError
from sara_app.human.analysis import containment
from sara_app.human.intake import screen
from sara_app.human.legs import containment as legs_containment
from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import MODELS, HumanReach
from sara_app.human.recordings import load_recording, shared_data_dir

HORIZON_S = 0.3


def _rec(name: str):
    try:
        d = shared_data_dir()
    except RecordingError:
        pytest.skip("CMU data folder not found")
    rec = load_recording(d / f"{name}.amc")
    return rec.slice(0, 1500) if name == "13_18" else rec  # first 12.5 s of boxing: CI budget


@pytest.fixture(scope="module")
def results():
    out = {}
    for clip in ("02_01", "09_06", "13_18"):
        rec = _rec(clip)
        for ps_name in ("schepp2022_table1", "cmu_calibrated", "work", "fast"):
            reach = HumanReach(to_reach_params(load_param_set(ps_name), rec.kind))
            out[clip, ps_name] = containment(reach, rec.times_s, rec.positions_m, HORIZON_S)
    return out


ACTIVITY = {"work": ("02_01",), "fast": ("02_01", "09_06", "13_18")}


@pytest.mark.parametrize("ps_name", sorted(ACTIVITY))
def test_activity_sets_contain_their_recordings_and_keep_the_monitor_quiet(
    results, ps_name: str
) -> None:
    """``work`` (walking) and ``fast`` (walking, running, boxing): every model contains every
    recording of the activity, the conformance monitor finds nothing beyond the bounds, and the
    height bound of legs an upper-body tracker would not measure holds over every horizon."""
    ps = load_param_set(ps_name)
    assert ps.legs_unmeasured is not None
    for clip in ACTIVITY[ps_name]:
        for h in (0.1, 0.2, 0.5):
            legs = legs_containment(_rec(clip), ps.legs_unmeasured, h, ps.delta_y_m)
            assert legs.misses == 0, (clip, h, legs)
        res = results[clip, ps_name]
        for m in MODELS:
            assert res[m].share == 1.0, (clip, m, res[m].misses_per_joint, res[m].worst[:2])
        rec = _rec(clip)
        p = to_reach_params(ps, rec.kind)
        s = screen(rec.times_s, rec.positions_m, p.delta_y_m, p.v_max_mps, p.a_max_mps2)
        assert s.counts["speed"] == s.counts["acceleration"] == 0, (clip, s.violations[:3])
        assert not s.held.any()


def test_calibrated_set_contains_every_clip_with_every_model(results) -> None:
    for clip in ("02_01", "09_06", "13_18"):
        for m in MODELS:
            res = results[clip, "cmu_calibrated"][m]
            assert res.share == 1.0, (clip, m, res.misses_per_joint, res.worst[:2])


def test_table1_walk_position_model_is_sound_acceleration_model_misses_a_heel_strike(
    results,
) -> None:
    walk = results["02_01", "schepp2022_table1"]
    assert walk["pos"].share == 1.0
    # The right heel strike at t = 2.408 s decelerates the ankle beyond 50 m/s^2: R_ACC with
    # Table I misses it by a few millimetres, and nothing else in the walk.
    acc = walk["acc"]
    assert set(acc.misses_per_joint) == {"r_ankle"}
    assert acc.worst[0].t_s == pytest.approx(2.408, abs=0.01)
    assert 0.0 < acc.worst[0].excess_m < 0.01


def test_table1_velocity_models_miss_the_walks_swinging_ankles(results) -> None:
    """Schepp et al. 2022 Table I's 2 m/s does not bound a plain walk's ankles (DESIGN sec. 6)."""
    walk = results["02_01", "schepp2022_table1"]
    for m in ("vel", "iso13855"):
        assert walk[m].share < 1.0
        assert {"l_ankle", "r_ankle"} <= set(walk[m].misses_per_joint)
        assert walk[m].worst[0].excess_m > 0.05


def test_table1_misses_boxing_hands_and_running_body(results) -> None:
    box = results["13_18", "schepp2022_table1"]
    for m in ("vel", "iso13855"):
        assert {"l_wrist", "r_wrist"} <= set(box[m].misses_per_joint)
    run = results["09_06", "schepp2022_table1"]
    assert run["vel"].share < 0.5  # the runner's whole body exceeds 2 m/s
    assert "pelvis" in run["vel"].misses_per_joint


SUBJECT_62_WALKS = ("62_03", "62_05", "62_06", "62_09", "62_11")


@pytest.mark.parametrize(("ps_name", "n_pieces"), [("work", 7), ("fast", 6)])
def test_walking_sets_contain_the_walks_of_a_second_subject(ps_name: str, n_pieces: int) -> None:
    """``work`` and ``fast`` are fitted to the walking pieces of CMU subject 62 (to the bench and
    away) as well: every model contains each piece and the monitor stays quiet. ``work`` (4 mm
    noise bound) leaves out the one reconstruction failure its fit split off (a head jump in
    62_11 beyond 400 m/s^2 over the noise: 7 pieces); under ``fast``'s 12 mm the jump is within
    the fitted bounds and the pieces are taken WHOLE (6)."""
    from sara_app.human.failures import Ceilings, split
    from sara_app.human.segments import walking_pieces

    try:
        shared_data_dir()
    except RecordingError:
        pytest.skip("CMU data folder not found")
    ps = load_param_set(ps_name)
    pieces = [q for n in SUBJECT_62_WALKS
              for p in walking_pieces(load_recording(n))
              for q in split(p, Ceilings(8.0, 400.0), ps.delta_y_m)[0]]  # fmt: skip
    assert len(pieces) == n_pieces
    for rec in pieces:
        p = to_reach_params(ps, rec.kind)
        res = containment(HumanReach(p), rec.times_s, rec.positions_m, HORIZON_S)
        for m in MODELS:
            assert res[m].share == 1.0, (rec.name, m, res[m].misses_per_joint, res[m].worst[:2])
        s = screen(rec.times_s, rec.positions_m, p.delta_y_m, p.v_max_mps, p.a_max_mps2)
        assert s.counts["speed"] == s.counts["acceleration"] == 0, (rec.name, s.violations[:3])
        assert ps.legs_unmeasured is not None
        for h in (0.1, 0.2, 0.5):  # the legs' height bound (fitted to the walking pieces)
            assert legs_containment(rec, ps.legs_unmeasured, h).misses == 0, (rec.name, h)
