"""The offline commands run end to end on a small CSV recording."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from sara_app.cli import main
from sara_app.human.recordings import Recording, save_csv
from sara_app.human.skeleton import FULL_JOINTS, UPPER_JOINTS


def _csv(tmp_path, kind="full", sway_m=0.3):
    """A small recording swaying ``sway_m`` along x; ``upper``: the 9 joints of an upper-body
    tracker (or of the TUM table-side recordings), named ``u``, else ``h``."""
    t = np.arange(0, 0.5, 1 / 60)
    n, low, name = (len(FULL_JOINTS), 0.1, "h") if kind == "full" else (len(UPPER_JOINTS), 0.9, "u")
    base = np.linspace([0, 0, low], [0.3, 0.2, 1.7], n)
    y = base[None] + sway_m * np.sin(2 * np.pi * t)[:, None, None] * np.array([1.0, 0, 0])
    path = tmp_path / f"{name}.csv"
    save_csv(Recording(name, kind, t, y, "test"), path)
    return path


def test_reach_writes_jsonl_and_reports(tmp_path, capsys) -> None:
    out = tmp_path / "caps.jsonl"
    assert main(["reach", str(_csv(tmp_path)), "--horizon", "0.1", "--out", str(out)]) == 0
    lines = [json.loads(x) for x in out.read_text().splitlines()]
    assert len(lines) == 30 * 6  # frames x models (pos, vel, acc, iso13855, arm, combined)
    first = lines[0]
    keys = {"frame", "t_s", "model", "horizon_s", "params", "available", "capsules"}
    assert set(first) == keys
    cap = first["capsules"][0]
    assert len(cap["p1"]) == 3 and cap["radius"] > 0
    # the first frame has no velocity estimate: acc is unavailable there, never a huge capsule
    acc0 = [x for x in lines if x["model"] == "acc" and x["frame"] == 0][0]
    assert acc0["available"] is False and acc0["capsules"] == []
    assert all(x["available"] for x in lines if x["frame"] > 0)
    text = capsys.readouterr().out
    assert "containment" in text and "vel" in text and "m^3" in text
    assert "unavailable for" in text and "tracking gate and conformance monitor" in text


def test_bad_recording_is_a_clear_error(tmp_path, capsys) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text("time_s,head_x\n0,1\n")
    assert main(["reach", str(bad)]) == 2
    assert "error:" in capsys.readouterr().err


def test_calibrate_writes_a_loadable_set(tmp_path) -> None:
    from sara_app.human.params import load_param_set

    out = tmp_path / "fit.json"
    assert main(["calibrate", str(_csv(tmp_path)), "--horizon", "0.1", "--out", str(out)]) == 0
    ps = load_param_set(out)
    assert ps.name == "calibrated" and ps.sound_for["models"]


def test_volumes_report_the_effective_set(tmp_path, capsys) -> None:
    """``sara-app volumes`` adds the per-body-part intersection of the models (what the verdict
    uses): never above the smallest model's volume (up to the Monte-Carlo error)."""
    from sara_app.human.report import volume_table

    table = volume_table(str(_csv(tmp_path)), "schepp2022_table1", [0.1, 0.3], None,
                         ("vel", "acc", "combined", "pos"))  # fmt: skip
    assert "effective" in capsys.readouterr().out
    for k in range(2):
        smallest = min(table[m][k] for m in ("vel", "acc", "combined", "pos"))
        assert 0.0 < table["effective"][k] <= 1.05 * smallest


def test_every_offline_command_takes_an_upper_body_recording(tmp_path, capsys) -> None:
    """An upper-body recording went through the tracking gate's leg bones (an IndexError in
    reach, volumes and calibrate); each command now runs on it end to end."""
    up = str(_csv(tmp_path, "upper"))
    out = tmp_path / "caps.jsonl"
    assert main(["reach", up, "--horizon", "0.1", "--out", str(out)]) == 0
    assert "containment on u" in capsys.readouterr().out
    assert main(["volumes", up, "--horizons", "0.1,0.2"]) == 0
    assert "effective" in capsys.readouterr().out
    cal = tmp_path / "cal.json"
    assert main(["calibrate", up, "--horizon", "0.1", "--out", str(cal)]) == 0
    assert json.loads(cal.read_text())["delta_y_m"] > 0
    # the legs' height bound needs legs: an upper-body recording is refused, saying so
    assert main(["legs", up, str(_csv(tmp_path)), "--out", str(tmp_path / "l.json")]) == 2
    assert "need a full-body recording" in capsys.readouterr().err


def _frames(tmp_path, n: int, name: str = "short", jump_m: float = 0.0):
    """A standing full-body recording of ``n`` frames at 60 Hz; ``jump_m`` added to every
    joint of frame 1 (a finite coordinate no person reaches)."""
    t = np.arange(n) / 60.0
    y = np.repeat(np.linspace([0, 0, 0.1], [0.3, 0.2, 1.7], len(FULL_JOINTS))[None], n, axis=0)
    if n > 1:
        y[1] += jump_m
    path = tmp_path / f"{name}.csv"
    save_csv(Recording(name, "full", t, y, "test"), path)
    return str(path)


@pytest.mark.parametrize("n", [1, 2])
def test_every_offline_command_refuses_a_recording_too_short_to_say_anything(
    tmp_path, capsys, n
) -> None:
    """One or two frames: no acceleration (and with one no velocity) to check or fit. Each
    command said "nan %" or ended in a ValueError or a KeyError; now each refuses, naming the
    recording and the frames it needs."""
    from sara_app.errors import RecordingError
    from sara_app.human.params import load_param_set
    from sara_app.report.evidence import _containment_rows

    short, ok = _frames(tmp_path, n), _csv(tmp_path)
    out = str(tmp_path / "o.json")
    for args in (["reach", short], ["volumes", short], ["calibrate", short, str(ok), "--out", out],
                 ["legs", str(ok), short, "--out", out],
                 ["displacement", str(ok), short, "--out", out]):  # fmt: skip
        assert main(args) == 2, args
        err = capsys.readouterr().err
        assert f"recording 'short' has {n} frame(s)" in err and "at least 3" in err, (args, err)
    with pytest.raises(RecordingError, match="has 2 frame"):  # the evidence report's too
        _containment_rows(load_param_set("bench_work"), ("pos",), [_frames(tmp_path, 2)])


def test_a_horizon_shorter_than_a_frame_checks_nothing_and_says_so(tmp_path, capsys) -> None:
    """No future frame within the horizon: ``reach`` says nothing was checked (it printed
    "nan %"); ``calibrate`` has nothing to fit and refuses, naming the frame interval (it ended
    in a ValueError)."""
    rec = _frames(tmp_path, 30)
    assert main(["reach", rec, "--horizon", "0.001"]) == 0
    text = capsys.readouterr().out
    assert "nan" not in text and text.count("nothing checked: no future position") == 7
    assert main(["calibrate", rec, "--horizon", "0.001", "--out", str(tmp_path / "c.json")]) == 2
    err = capsys.readouterr().err
    assert "no two frames" in err and "0.01667 s" in err


def test_calibrate_refuses_bad_numbers_before_fitting(tmp_path, capsys) -> None:
    """A negative or NaN noise bound was fitted with and written (a set the loader then
    refused); a negative horizon reached the fit. The command line refuses them by the options'
    types (tests/test_numbers.py), and the command's function too, for callers of the API."""
    from sara_app.errors import InputError
    from sara_app.human.report import calibrate_command

    rec, out = _frames(tmp_path, 30), tmp_path / "c.json"
    for opts in (["--delta-y", "-1"], ["--delta-y", "nan"], ["--horizon", "-1"]):
        with pytest.raises(SystemExit) as e:
            main(["calibrate", rec, *opts, "--out", str(out)])
        assert e.value.code == 2 and f"'{opts[1]}'; expected" in capsys.readouterr().err
    for kw, said in (({"delta_y_m": -1.0}, "noise bound -1.0 m"),
                     ({"delta_y_m": float("nan")}, "noise bound nan m"),
                     ({"horizon_s": float("inf")}, "horizon inf s")):  # fmt: skip
        args = {"recordings": [rec], "horizon_s": 0.5, "base": "bench_work", "name": "x",
                "out": out} | kw  # fmt: skip
        with pytest.raises(InputError, match=said):
            calibrate_command(**args)
        assert not out.exists()
    for horizons in ("", "0.1,nan", "-1", "0.1,,0.2", "x"):
        with pytest.raises(SystemExit) as e:
            main(["volumes", rec, f"--horizons={horizons}"])
        assert e.value.code == 2
        assert "expected comma-separated seconds" in capsys.readouterr().err
    assert main(["volumes", rec, "--horizons", "0.1,0.2"]) == 0


def test_a_miss_by_an_absurd_coordinate_is_listed_with_its_size(tmp_path, capsys) -> None:
    """A finite coordinate whose square overflows: its misses were counted but the list of the
    worst was empty (not finite, dropped); now it leads the list in words, and one merely far
    off in metres."""
    for jump, said in (
        (1e300, r"by more than any finite distance"),
        (1e6, r"by \d\.\d+e\+0[67] m"),
    ):
        rec = _frames(tmp_path, 30, f"j{jump:g}", jump)
        assert main(["reach", rec, "--horizon", "0.1"]) == 0
        worst = [x for x in capsys.readouterr().out.splitlines() if "worst:" in x]
        assert len(worst) == 7 and all(re.search(said, x) for x in worst), (jump, worst)


def _two(tmp_path, second: str = "full") -> list[str]:
    """Two recordings in folders of their own (their names are the file's)."""
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    return [str(_csv(a)), str(_csv(b, second))]


def test_the_legs_command_fits_full_body_recordings_and_refuses_one(tmp_path, capsys) -> None:
    files = _two(tmp_path)
    out = tmp_path / "legs.json"
    assert main(["legs", *files, "--out", str(out)]) == 0
    assert "each recording left out" in capsys.readouterr().out
    assert json.loads(out.read_text())["legs_unmeasured"]["rise_max_mps"] > 0
    assert main(["legs", files[0], "--out", str(out)]) == 2
    assert "at least 2 recordings" in capsys.readouterr().err


def test_the_displacement_command_validates_and_writes_a_loadable_set(tmp_path, capsys) -> None:
    """Two recordings (one upper-body): each left out against the other's table, then the
    table fitted on both in the written set; the legs, which only one measures, keep v_max."""
    from sara_app.human.params import load_param_set

    files = _two(tmp_path, "upper")
    out = tmp_path / "d.json"
    assert main(["displacement", *files, "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "each recording left out" in text and "  h: 0.1 s" in text and "  u: 0.1 s" in text
    ps = load_param_set(out)
    d = ps.displacement
    assert d is not None and len(d.max_m["head"]) == 50
    # the sway (0.3 m at 1 Hz: at most 0.6 m in 0.45 s) is slower than the 2 m/s floor; the
    # recordings (0.48 s) say nothing past 0.48 s, nor of the legs by default: v_max there
    head, knee = d.max_m["head"], d.max_m["l_knee"]
    assert head[44] == 0.9 and head[-1] == ps.joints["head"].v_max_mps / 2
    assert knee[44] == pytest.approx(ps.joints["l_knee"].v_max_mps * 0.45, abs=1e-3)
    assert set(json.loads(ps.sound_for["displacement_left_out_misses_unflagged"])) == {"h", "u"}
    args = ["--floor-speed", "0", "--with-legs", "--out", str(out)]
    assert main(["displacement", *files, *args]) == 0
    d = load_param_set(out).displacement
    assert d is not None and d.max_m["head"][44] < 0.61 and d.max_m["l_knee"][44] < 0.61
    with pytest.raises(SystemExit):  # refused by the option's type (tests/test_numbers.py)
        main(["displacement", *files, "--margin", "0.5", "--out", str(out)])
    assert "argument --margin: '0.5'; expected a finite number >= 1" in capsys.readouterr().err
    nowhere = str(tmp_path / "no" / "such" / "d.json")  # a folder that does not exist
    assert main(["displacement", *files, "--out", nowhere]) == 2
    assert "cannot write parameter set 'bench_work' to " in capsys.readouterr().err


def test_calibrate_validates_leaving_each_recording_out(tmp_path, capsys) -> None:
    cal = tmp_path / "cal.json"
    files = _two(tmp_path, "upper")
    assert (
        main(["calibrate", *files, "--horizon", "0.1", "--leave-one-out", "--out", str(cal)]) == 0
    )
    text = capsys.readouterr().out
    assert "leave-one-recording-out validation" in text and "margin the shipped set needs" in text
    sound = json.loads(cal.read_text())["sound_for"]
    assert set(json.loads(sound["leave_one_out"])) == {"h", "u"}
    assert all(float(m) >= 1.0 for m in sound["margin_v_a_arm"].split(", "))
    assert main(["calibrate", files[0], "--leave-one-out", "--out", str(cal)]) == 2
    assert "at least two recordings" in capsys.readouterr().err


def test_calibrate_can_validate_without_widening(tmp_path, capsys) -> None:
    """``--no-widen``: the same left-out rows, the bounds of the fit alone, and the margin in the
    record as declined (never as applied); without ``--leave-one-out`` it is refused."""
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()  # the second sways twice as fast: left out, it needs a margin on the first's fit
    files = [str(_csv(a)), str(_csv(b, sway_m=0.6))]
    runs = {}
    for name, extra in (("fit", []), ("wide", ["--leave-one-out"]),
                        ("kept", ["--leave-one-out", "--no-widen"])):  # fmt: skip
        out = tmp_path / f"{name}.json"
        assert main(["calibrate", *files, "--horizon", "0.1", *extra, "--out", str(out)]) == 0
        runs[name] = json.loads(out.read_text())
    fit, wide, kept = runs["fit"], runs["wide"], runs["kept"]
    assert kept["joints"] == fit["joints"] and kept["arm"] == fit["arm"]
    margin = [float(m) for m in wide["sound_for"]["margin_v_a_arm"].split(", ")]
    assert max(margin) > 1.0  # else widening and not widening could not be told apart
    assert kept["joints"] != wide["joints"]
    record = kept["sound_for"]
    assert "margin_v_a_arm" not in record
    assert record["margin_declined_v_a_arm"] == wide["sound_for"]["margin_v_a_arm"]
    assert record["leave_one_out"] == wide["sound_for"]["leave_one_out"]
    assert "not widened by the margin" in kept["description"]
    assert "then by the margin" in wide["description"]
    capsys.readouterr()
    assert main(["calibrate", *files, "--no-widen", "--out", str(tmp_path / "x.json")]) == 2
    assert "--no-widen" in capsys.readouterr().err


def test_a_bvh_unit_and_up_axis_are_options_of_bvh_files_only(tmp_path, capsys) -> None:
    assert main(["reach", str(_csv(tmp_path)), "--unit", "mm"]) == 2
    assert "only for BVH files" in capsys.readouterr().err


def test_calibrate_splits_off_reconstruction_failures_under_both_ceilings(tmp_path, capsys) -> None:
    cal = tmp_path / "cal.json"
    rec = str(_csv(tmp_path))
    args = ["calibrate", rec, "--horizon", "0.1", "--out", str(cal)]
    assert main([*args, "--max-speed", "8", "--max-acc", "400"]) == 0
    assert "reconstruction failures left out (ceilings 8 m/s, 400 m/s^2)" in capsys.readouterr().out
    sound = json.loads(cal.read_text())["sound_for"]
    assert sound["ceilings"].startswith("8 m/s, 400 m/s^2")
    assert "reconstruction_failures_left_out" in sound
    assert main([*args, "--max-speed", "8"]) == 2
    assert "--max-speed and --max-acc go together" in capsys.readouterr().err
