"""The walking pieces of a recording (sara_app.human.segments): where the pelvis moves over the
floor, found on synthetic recordings whose walk is known, and on the CMU recordings."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sara_app.cli import main
from sara_app.errors import ParameterError, RecordingError
from sara_app.human.recordings import Recording, load_recording, save_csv, shared_data_dir
from sara_app.human.scripted import joints, standing
from sara_app.human.segments import MIN_DURATION_S, pelvis_speed, walking_pieces

RATE_HZ = 120.0


def _person(phases: list[tuple[float, float]], name: str = "w") -> Recording:
    """A standing pose carried along x: ``phases`` of (seconds, speed m/s) one after the other
    (speed 0: standing), with the arms swinging a little all the time (not a walk)."""
    y0 = joints(standing((0.0, 0.0), 0.0))
    v = np.concatenate([np.full(int(round(s * RATE_HZ)), speed) for s, speed in phases])
    t = np.arange(v.size) / RATE_HZ
    x = np.concatenate([[0.0], np.cumsum(v[1:]) / RATE_HZ])
    y = np.repeat(y0[None], v.size, axis=0)
    y[:, :, 0] += x[:, None]
    y[:, :, 2] += 0.02 * np.sin(2 * np.pi * 1.5 * t)[:, None]  # weight shifts: not walking
    return Recording(name, "full", t, y, "test")


def test_a_walk_between_two_stands_is_one_piece_with_its_window() -> None:
    rec = _person([(1.0, 0.0), (1.5, 1.2), (1.0, 0.0)])
    (piece,) = walking_pieces(rec)
    t = piece.times_s
    # the walk is 1.0-2.5 s; the central difference sees it up to a half window early and
    # late, and the piece takes in the window of its first and last differences
    assert 0.7 <= t[0] <= 1.0 and 2.5 <= t[-1] <= 2.8
    assert np.array_equal(piece.positions_m, rec.positions_m[np.isin(rec.times_s, t)])
    assert piece.name.startswith("w@")


def test_standing_a_short_step_and_a_slow_shuffle_are_not_walking() -> None:
    assert walking_pieces(_person([(2.0, 0.0)])) == []
    assert walking_pieces(_person([(1.0, 0.0), (MIN_DURATION_S / 2, 1.2), (1.0, 0.0)])) == []
    assert walking_pieces(_person([(1.0, 0.0), (2.0, 0.3), (1.0, 0.0)])) == []


def test_a_recording_that_walks_from_its_first_frame_is_walking_whole() -> None:
    """The first and last half window have no central difference of their own: the piece still
    takes them in."""
    rec = _person([(2.0, 1.0)])
    assert np.isnan(pelvis_speed(rec)[:5]).all()
    (piece,) = walking_pieces(rec)
    assert piece.n_frames == rec.n_frames


def test_two_walks_are_two_pieces_and_bad_settings_are_refused() -> None:
    rec = _person([(1.0, 1.2), (1.5, 0.0), (1.0, 1.4)])
    assert len(walking_pieces(rec)) == 2
    for bad in ({"min_speed_mps": 0.0}, {"min_duration_s": -1.0}, {"half_window_s": float("nan")}):
        with pytest.raises(ParameterError, match="expected positive"):
            walking_pieces(rec, **bad)


def test_calibrate_on_walking_pieces_leaves_the_standing_out(tmp_path, capsys) -> None:
    """``sara-app calibrate --walking``: the standing recording is left out (said so), the set is
    fitted to the walks, and its description says how."""
    files = []
    for name, phases in (("a", [(1.0, 0.0), (1.5, 1.2)]), ("b", [(1.0, 1.4), (1.0, 0.0)]),
                         ("c", [(2.0, 0.0)])):  # fmt: skip
        (tmp_path / name).mkdir()
        files.append(tmp_path / name / f"{name}.csv")
        save_csv(_person(phases, name), files[-1])
    out = tmp_path / "walk.json"
    args = ["calibrate", *map(str, files), "--walking", "--leave-one-out", "--horizon", "0.1"]
    assert main([*args, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "c: walking pieces none: left out" in text and "a: walking pieces 0.88-2.49s" in text
    ps = json.loads(out.read_text())
    assert set(json.loads(ps["sound_for"]["leave_one_out"])) == {"a", "b"}
    assert "walking pieces" in ps["description"] and "margin" in ps["description"]
    assert main(["calibrate", str(files[2]), "--walking", "--out", str(out)]) == 2
    assert "none of the recordings has a walking piece" in capsys.readouterr().err
    # one recording's walking pieces beside another one whole
    assert main(["calibrate", f"{files[0]}@walking", str(files[2]), "--horizon", "0.1",
                 "--out", str(out)]) == 0  # fmt: skip
    assert "a: walking pieces 0.88-2.49s" in capsys.readouterr().out
    described = json.loads(out.read_text())["description"]
    assert "on a@walking, c (@walking: walking pieces" in described
    assert set(json.loads(json.loads(out.read_text())["sound_for"]["misses_per_recording"])) == {
        "a", "c"}  # fmt: skip


def test_cmu_walk_is_walking_whole_and_bench_work_walks_in_and_out() -> None:
    try:
        shared_data_dir()
    except RecordingError:
        pytest.skip("CMU data folder not found")
    walk = load_recording("02_01")
    (piece,) = walking_pieces(walk)
    assert piece.n_frames == walk.n_frames
    assert walking_pieces(load_recording("62_01")) == []  # bolts at the bench, no walk
    assert len(walking_pieces(load_recording("62_11"))) == 2  # walks in, works, walks off
