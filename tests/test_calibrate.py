"""Calibration widens bounds exactly enough to contain a recording, and names its drivers."""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.human.analysis import containment
from sara_app.human.calibrate import calibrate, fit_velocity
from sara_app.human.intake import screen
from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.recordings import Recording, load_recording
from sara_app.human.skeleton import FULL_JOINTS


def _synthetic(speed_mps: float, glitch: bool = False) -> Recording:
    """A standing figure whose right wrist oscillates with peak speed ``speed_mps``."""
    t = np.arange(0, 2.0, 1 / 120)
    base = np.array(
        [
            [0, 0, 1.65],
            [0, 0, 1.45],
            [0, 0, 0.95],
            [-0.18, 0, 1.42],
            [0.18, 0, 1.42],
            [-0.2, 0.05, 1.13],
            [0.2, 0.05, 1.13],
            [-0.2, 0.25, 1.0],
            [0.22, 0.28, 1.02],
            [-0.1, 0, 0.92],
            [0.1, 0, 0.92],
            [-0.1, 0.02, 0.5],
            [0.1, 0.02, 0.5],
            [-0.1, 0, 0.08],
            [0.1, 0, 0.08],
        ]
    )
    y = np.repeat(base[None], len(t), axis=0)
    w = 2 * np.pi * 2.0
    y[:, 8, 1] += speed_mps / w * np.sin(w * t)
    if glitch:
        y[100, 8, 2] += 0.2  # one frame of tracking glitch
    return Recording("synthetic", "full", t, y, "test")


def test_fit_velocity_finds_the_peak_speed_and_its_frame() -> None:
    rec = _synthetic(3.0)
    v, drivers = fit_velocity([rec], FULL_JOINTS, 0.0, 0.3)
    j = FULL_JOINTS.index("r_wrist")
    assert v[j] == pytest.approx(3.0, rel=0.01)
    assert v[0] == 0.0  # the head does not move
    # the fastest crossing of the centre is at t = k/4 s (zero phase, every half period)
    assert min(abs(drivers[j][0].t_s - k / 4) for k in range(8)) < 0.03


def _velocity_oracle(rec: Recording, delta_y_m: float, horizon_s: float) -> np.ndarray:
    """Brute force over every frame pair within the horizon: the least v_max per joint."""
    t, y = rec.times_s, rec.positions_m
    best = np.zeros(y.shape[1])
    for i in range(len(t)):
        for j in range(i + 1, len(t)):
            tau = t[j] - t[i]
            if tau > horizon_s + 1e-12:
                break
            d = np.linalg.norm(y[j] - y[i], axis=-1)
            best = np.maximum(best, (d - delta_y_m) / tau)
    return best


def test_a_gap_in_the_stamps_keeps_every_pair_within_the_horizon() -> None:
    """A tracker that dropped frames at the start (0.3 s between its first two frames, 120 Hz
    after): the fit looked only as many frames ahead as the FIRST frame has within the horizon
    (26 for 0.5 s), so every later pair 0.21-0.5 s apart was left out and the fitted speed fell
    short of the motion (for a steady wrist, (|d| - delta_y) / tau grows with tau). Against the
    brute-force oracle, in chunks of any size."""
    rec = _synthetic(0.0)
    rec.positions_m[:, 8, 1] += 1.0 * rec.times_s  # the right wrist at a steady 1 m/s
    keep = np.r_[0, np.arange(36, len(rec.times_s))]  # frame 0, then from t = 0.3 s
    y = rec.positions_m[keep]
    y[0] = y[1]  # still until the tracker's second frame: frame 0's own pairs drive nothing
    gap = Recording("gap", "full", rec.times_s[keep], y, "test")
    want = _velocity_oracle(gap, 0.01, 0.5)
    v, drivers = fit_velocity([gap], FULL_JOINTS, 0.01, 0.5)
    np.testing.assert_allclose(v, want, rtol=0, atol=1e-12)
    j = FULL_JOINTS.index("r_wrist")
    assert drivers[j][0].value == pytest.approx(want[j], abs=1e-12)
    assert drivers[j][0].tau_s == pytest.approx(0.5)  # the longest pairs, left out before


def test_glitch_frame_is_reported_as_driver() -> None:
    rec = _synthetic(1.0, glitch=True)
    _, drivers = fit_velocity([rec], FULL_JOINTS, 0.004, 0.3)
    j = FULL_JOINTS.index("r_wrist")
    assert any(
        abs(d.t_s - rec.times_s[100]) < 1e-9 or abs(d.t_s + d.tau_s - rec.times_s[100]) < 1e-9
        for d in drivers[j]
    )


def test_calibrated_set_contains_what_the_base_set_misses() -> None:
    rec = _synthetic(3.5)
    base = load_param_set("schepp2022_table1")
    before = containment(
        HumanReach(to_reach_params(base, "full")), rec.times_s, rec.positions_m, 0.3
    )
    assert before["vel"].share < 1.0 and before["iso13855"].share < 1.0
    ps, rep = calibrate(base, [rec], 0.3, "synthetic_fit")
    after = containment(HumanReach(to_reach_params(ps, "full")), rec.times_s, rec.positions_m, 0.3)
    for m, res in after.items():
        assert res.share == 1.0, (m, res.worst[:2])
    # delta_y absorbs part of the displacement over one frame, so the need is below the peak
    assert 3.0 < ps.joints["r_wrist"].v_max_mps < 3.6
    assert ps.joints["head"].v_max_mps == base.joints["head"].v_max_mps  # never tightened
    assert rep.drivers_v["r_wrist"]


def test_bounds_are_rounded_up_onto_a_grid_a_person_reads() -> None:
    """A fitted bound is rounded UP (never below what the recordings need) onto the 0.01 m/s
    grid and written without float residue (531 * 0.01 is 5.3100000000000005)."""
    from sara_app.human.calibrate import _round_up

    need = np.linspace(0.3, 9.0, 2001)
    v = _round_up(need, 1.01, 0.01)
    assert np.all(v >= need * 1.01)
    assert np.all(v - need * 1.01 < 0.01 + 1e-12)
    assert all(len(repr(float(x)).split(".")[1]) <= 2 for x in v), v
    a = _round_up(need * 50, 1.0, 1.0)
    assert np.all(a >= need * 50) and np.all(a == np.round(a))


def test_frames_the_gate_distrusts_are_left_out_and_listed() -> None:
    """The shipped walk (rigid bones) with its right wrist label swapped to the head for 10
    frames: without the gate the fit would need tens of m/s; the gate blames the wrist's bone,
    the frames are excluded and listed, and the wrist's bound is the walk's own (2.36 m/s
    without the swap). The calibrated set keeps the monitor quiet on the recording."""
    walk = load_recording("02_01")
    rng = np.random.default_rng(0)
    y = walk.positions_m + rng.uniform(-1, 1, walk.positions_m.shape) * 0.001
    y[120:130, 8] = y[120:130, 0]  # r_wrist reported at the head
    rec = Recording("swapped", "full", walk.times_s, y, "test")
    base = load_param_set("schepp2022_table1")
    ps, rep = calibrate(base, [rec], 0.3, "swap_fit", delta_y_m=0.005)
    assert ps.delta_y_m == rep.delta_y_m == 0.005
    assert rep.excluded["swapped"] == ["bone r_wrist: 10 frames"]
    assert ps.joints["r_wrist"].v_max_mps < 2.5
    assert rep.noise_m["r_wrist"] > 0.1  # the swap shows in the raw chord deviation
    p = to_reach_params(ps, "full")
    s = screen(rec.times_s, y, p.delta_y_m, p.v_max_mps, p.a_max_mps2)
    assert s.counts["speed"] == s.counts["acceleration"] == 0


def test_the_combined_model_contains_what_it_was_calibrated_on() -> None:
    """The speed and acceleration bounds are fitted on displacements; the combined model takes
    them as instantaneous bounds and can miss where each alone contains (CMU 62_15's right knee
    at a heel strike). The raise that closes the gap, given a set too slow for the shipped walk:
    the joints the combined model misses are raised until it contains the walk, no others."""
    from sara_app.human.calibrate import _fit_combined

    walk = load_recording("02_01")
    base = load_param_set("schepp2022_table1")
    reach = HumanReach(to_reach_params(base, "full"))
    before = containment(reach, walk.times_s, walk.positions_m, 0.2, models=("combined",))
    missed = set(before["combined"].misses_per_joint)
    assert missed  # Table I's 2 m/s is too slow for the walk's ankles
    ps, raised = _fit_combined(base, [walk], 0.2)
    assert set(raised) == missed
    assert all(ps.joints[j].v_max_mps > base.joints[j].v_max_mps for j in raised)
    reach = HumanReach(to_reach_params(ps, "full"))
    after = containment(reach, walk.times_s, walk.positions_m, 0.2, models=("combined",))
    assert after["combined"].contained == after["combined"].checked
