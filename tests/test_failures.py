"""Reconstruction failures (sara_app.human.failures): a limb that flips away and back, a swing
out and back and a one-frame spike are found whole and split off; motion within the ceilings and
tracker noise within delta_y are not; a fit on the pieces is the fit of the motion alone."""

from __future__ import annotations

import numpy as np
import pytest
from test_calibrate import _synthetic

from sara_app.errors import ParameterError
from sara_app.human.calibrate import calibrate
from sara_app.human.failures import Ceilings, describe, find_failures, pieces, split
from sara_app.human.params import load_param_set
from sara_app.human.recordings import Recording
from sara_app.human.skeleton import FULL_JOINTS

CEILINGS = Ceilings(8.0, 400.0)
DY = 0.004
J = FULL_JOINTS.index("l_wrist")


def _with(rec: Recording, frames: slice, offset_m: np.ndarray) -> Recording:
    y = rec.positions_m.copy()
    y[frames, J] += offset_m
    return Recording("flip", rec.kind, rec.times_s, y, "test")


def test_a_flip_is_one_failure_and_the_fit_on_the_pieces_is_the_motions() -> None:
    rec = _synthetic(2.5)
    # away and back, 0.32 m (38 m/s), the forearm still a person's length (0.46 m): a flip the
    # gate's anatomy check cannot see (0.6 m away, the forearm 0.81 m, it holds the wrist)
    bad = _with(rec, slice(120, 122), np.array([0.0, 0.25, 0.2]))
    (f,) = find_failures(bad, CEILINGS, DY)
    pad = int(np.ceil(CEILINGS.margin_s * 120))
    assert f.first == 119 - pad and f.last == 122 + pad and f.joints == "l_wrist"
    parts = pieces(bad, [f])
    assert [p.n_frames for p in parts] == [f.first, bad.n_frames - f.last - 1]
    assert np.array_equal(parts[1].positions_m, bad.positions_m[f.last + 1 :])
    assert "flip: 0.9" in describe(bad, [f])[0]
    base = load_param_set("schepp2022_table1")
    wild = calibrate(base, [bad], 0.2, "wild")[0]
    tame = calibrate(base, parts, 0.2, "tame")[0]
    clean = calibrate(base, pieces(rec, [f]), 0.2, "clean")[0]
    assert wild.joints["l_wrist"].v_max_mps > 10.0
    assert tame.joints["l_wrist"].v_max_mps == clean.joints["l_wrist"].v_max_mps < 3.0


def test_a_swing_out_and_back_is_split_off_whole() -> None:
    """A limb swung 0.9 m out and back over 20 frames (peak 9 m/s): its slower frames belong to
    the failure too (hysteresis at half the ceiling), so no piece keeps part of it."""
    rec = _synthetic(0.5)
    n = 20
    bump = 0.9 * np.sin(np.linspace(0.0, np.pi, n)) ** 2  # peak speed ~ 0.9 pi 120 / 20 ~ 17 m/s
    y = rec.positions_m.copy()
    y[100 : 100 + n, J, 1] += bump
    bad = Recording("swing", rec.kind, rec.times_s, y, "test")
    speed = np.abs(np.diff(y[:, J, 1])) * 120
    (f,) = find_failures(bad, CEILINGS, DY)
    moving = np.flatnonzero(speed > 0.5)  # every frame of the swing
    assert f.first <= moving[0] and f.last >= moving[-1] + 1


def test_a_one_frame_spike_below_the_speed_ceiling_is_found_by_its_acceleration() -> None:
    rec = _synthetic(0.5)
    bad = _with(rec, slice(150, 151), np.array([0.0, 0.0, 0.03]))  # 3.6 m/s, 8 600 m/s^2
    (f,) = find_failures(bad, CEILINGS, DY)
    assert f.first <= 150 <= f.last and f.joints == "l_wrist"


def test_motion_within_the_ceilings_and_noise_within_delta_y_are_kept() -> None:
    rng = np.random.default_rng(3)
    rec = _synthetic(6.0)  # a wrist at 6 m/s peak (2 Hz, so about 150 m/s^2)
    noisy = rec.positions_m + rng.uniform(-1, 1, rec.positions_m.shape) * DY / np.sqrt(3)
    rec = Recording("fast", rec.kind, rec.times_s, noisy, "test")
    assert find_failures(rec, CEILINGS, DY) == []
    assert split(rec, CEILINGS, DY) == ([rec], [])
    assert split(rec, None, DY) == ([rec], [])


@pytest.mark.parametrize("args", [(0.0, 400.0), (8.0, float("nan")), (8.0, 400.0, -1.0)])
def test_ceilings_must_be_positive_and_finite(args: tuple[float, ...]) -> None:
    with pytest.raises(ParameterError, match="expected a finite value"):
        Ceilings(*args)
