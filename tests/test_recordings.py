"""Recordings: CMU ASF/AMC forward kinematics against PROVENANCE.md, the CSV format, validate()."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

from sara_app.errors import InputError, RecordingError
from sara_app.human.cmu import CMU_TO_WORLD, cmu_rest_bones, load_cmu, load_cmu_bones
from sara_app.human.recordings import (
    Recording,
    load_csv,
    load_recording,
    save_csv,
    shared_data_dir,
    validate,
)
from sara_app.human.skeleton import FULL_JOINTS, UPPER_JOINTS, skeleton

FPS = 120.0


@pytest.fixture(scope="module")
def data_dir() -> Path:
    try:
        return shared_data_dir()
    except RecordingError as exc:
        pytest.skip(f"CMU data not found: {exc}")


@pytest.fixture(scope="module")
def walk(data_dir: Path) -> Recording:
    return load_recording(data_dir / "02_01.amc")


@pytest.fixture(scope="module")
def boxing_bones(data_dir: Path) -> dict[str, np.ndarray]:
    # 3000 frames, 2.4 MB: parsed once for the module.
    return load_cmu_bones(data_dir / "13.asf", data_dir / "13_18.amc")


def _j(name: str) -> int:
    return FULL_JOINTS.index(name)


def _dist(p: np.ndarray, a: str, b: str) -> np.ndarray:
    return np.linalg.norm(p[:, _j(a)] - p[:, _j(b)], axis=-1)


def _peak_speed(x: np.ndarray, fps: float = FPS) -> float:
    """Peak speed of a (T, 3) track: 5-frame moving average, then central differences."""
    k = np.ones(5) / 5
    xs = np.stack([np.convolve(x[:, i], k, mode="valid") for i in range(3)], axis=1)
    v = (xs[2:] - xs[:-2]) * fps / 2
    return float(np.linalg.norm(v, axis=1).max())


def _rec(n: int = 4, kind: str = "full") -> Recording:
    rng = np.random.default_rng(0)
    j = skeleton(kind).n_joints
    return Recording("synthetic", kind, np.arange(n) / 10.0, rng.normal(size=(n, j, 3)), "test")


# --- CMU -----------------------------------------------------------------------------------


def test_axis_conversion_is_a_proper_rotation() -> None:
    assert np.allclose(CMU_TO_WORLD @ CMU_TO_WORLD.T, np.eye(3))
    assert np.isclose(np.linalg.det(CMU_TO_WORLD), 1.0)
    assert np.allclose(CMU_TO_WORLD @ [0, 1, 0], [0, 0, 1])  # CMU up (y) -> world up (z)


def test_walk_loads(walk: Recording) -> None:
    assert walk.name == "02_01"
    assert walk.kind == "full"
    assert walk.times_s.shape == (343,)
    assert walk.positions_m.shape == (343, len(FULL_JOINTS), 3)
    assert np.isfinite(walk.positions_m).all()
    assert walk.frame_period_s == pytest.approx(1 / 120)
    assert walk.times_s[0] == 0.0
    assert "02.asf" in walk.source and "02_01.amc" in walk.source


def test_load_by_name_and_by_pair(data_dir: Path, walk: Recording) -> None:
    by_name = load_recording("02_01")
    by_pair = load_cmu(data_dir / "02.asf", data_dir / "02_01.amc", fps=60.0, name="w")
    assert np.array_equal(by_name.positions_m, walk.positions_m)
    assert np.array_equal(by_pair.positions_m, walk.positions_m)
    assert by_pair.frame_period_s == pytest.approx(1 / 60) and by_pair.name == "w"


def test_walk_body_dimensions(walk: Recording) -> None:
    p = walk.positions_m
    limbs = {
        # CMU subject 02: humerus 0.275 / 0.284 m.
        ("l_shoulder", "l_elbow"): (0.25, 0.35),
        ("r_shoulder", "r_elbow"): (0.25, 0.35),
        # The CMU radius bone (elbow to the start of the 'wrist' bone) is short: 0.189 m for
        # subject 02, 0.20-0.21 m for subjects 09 and 13; hence the lower limit 0.17.
        ("l_elbow", "l_wrist"): (0.17, 0.30),
        ("r_elbow", "r_wrist"): (0.17, 0.30),
        ("l_hip", "l_knee"): (0.35, 0.50),
        ("r_hip", "r_knee"): (0.35, 0.50),
        ("l_knee", "l_ankle"): (0.35, 0.50),
        ("r_knee", "r_ankle"): (0.35, 0.50),
        ("l_shoulder", "r_shoulder"): (0.30, 0.45),
        ("l_hip", "r_hip"): (0.12, 0.30),
    }
    for (a, b), (lo, hi) in limbs.items():
        d = _dist(p, a, b)
        assert lo < d.mean() < hi, (a, b, d.mean())
        # Each of these is one rigid CMU bone (or two joined without dof): FK keeps it constant.
        assert d.std() < 1e-3, (a, b, d.std())
    # Standing height, head centre above the ankles: about 1.5 m for a 1.5-1.6 m subject.
    h = p[0, _j("head"), 2] - p[0, [_j("l_ankle"), _j("r_ankle")], 2].min()
    assert 1.3 < h < 1.7


def test_walk_is_z_up_and_horizontal(walk: Recording) -> None:
    p = walk.positions_m
    head, pelvis = p[:, _j("head"), 2], p[:, _j("pelvis"), 2]
    ankles = p[:, [_j("l_ankle"), _j("r_ankle")], 2].max(axis=1)
    assert (head > pelvis).all() and (pelvis > ankles).all()
    travel = np.linalg.norm(p[-1, _j("pelvis"), :2] - p[0, _j("pelvis"), :2])
    assert travel > 1.0  # 3.4 m in 2.9 s
    assert np.ptp(pelvis) < 0.15 < 0.1 * travel  # 0.07 m vertical bobbing


def test_walk_left_is_left(walk: Recording) -> None:
    # No mirroring: with z up and the walking direction f, the left side lies along z x f.
    p = walk.positions_m
    f = p[-1, _j("pelvis")] - p[0, _j("pelvis")]
    left = np.cross([0.0, 0.0, 1.0], [f[0], f[1], 0.0])
    assert ((p[:, _j("l_shoulder")] - p[:, _j("r_shoulder")]) @ left > 0).all()
    assert ((p[:, _j("l_hip")] - p[:, _j("r_hip")]) @ left > 0).all()


def _first_frame_height(bones: dict[str, np.ndarray]) -> float:
    """Top of the 'head' bone above the lowest foot or toe point, first frame."""
    feet = min(bones[k][0, 2] for k in ("lfoot", "rfoot", "ltoes", "rtoes"))
    return float(bones["head"][0, 2] - feet)


@pytest.mark.parametrize("subject, height_m", [("13", 1.63), ("09", 1.57)])
def test_subject_heights_match_provenance(data_dir: Path, subject: str, height_m: float) -> None:
    # PROVENANCE's heights are those of the ASF rest pose (all angles 0): top of the 'head' bone
    # above the lowest point (the toes). Measured: 1.628 m (13) and 1.571 m (09).
    rest = cmu_rest_bones(data_dir / f"{subject}.asf")
    z = np.array([v[2] for v in rest.values()])
    assert rest["head"][2] - z.min() == pytest.approx(height_m, abs=0.01)


def test_first_frame_heights(data_dir: Path, boxing_bones: dict[str, np.ndarray]) -> None:
    # In the first frame of a clip (boxing stance, running stride) the subject stands a little
    # lower than in the rest pose: measured 1.610 m (13, rest 1.628) and 1.549 m (09, rest 1.571).
    assert boxing_bones["root"].shape == (3000, 3)
    assert _first_frame_height(boxing_bones) == pytest.approx(1.63, abs=0.05)
    run = load_cmu_bones(data_dir / "09.asf", data_dir / "09_06.amc")
    assert run["root"].shape == (141, 3)
    assert _first_frame_height(run) == pytest.approx(1.57, abs=0.05)


def test_boxing_hand_speed(boxing_bones: dict[str, np.ndarray]) -> None:
    # PROVENANCE: peak 7.2 m/s at the hand, 6.3 m/s at the wrist (world frame, central
    # differences on 5-frame smoothed positions). Measured here: 7.22 (lhand end) and 6.25
    # (rradius end = the project's r_wrist).
    hand = max(_peak_speed(boxing_bones[b]) for b in ("lhand", "rhand"))
    wrist = max(_peak_speed(boxing_bones[b]) for b in ("lradius", "rradius"))
    assert hand > 5.0 and wrist > 5.0
    assert hand == pytest.approx(7.2, abs=0.15)
    assert wrist == pytest.approx(6.3, abs=0.15)


def test_joint_mapping(data_dir: Path, walk: Recording) -> None:
    bones = load_cmu_bones(data_dir / "02.asf", data_dir / "02_01.amc")
    expected = {
        "head": 0.5 * (bones["upperneck"] + bones["head"]),
        "neck": bones["thorax"],
        "pelvis": bones["root"],
        **{f"{s}_shoulder": bones[f"{s}clavicle"] for s in "lr"},
        **{f"{s}_elbow": bones[f"{s}humerus"] for s in "lr"},
        **{f"{s}_wrist": bones[f"{s}radius"] for s in "lr"},
        **{f"{s}_hip": bones[f"{s}hipjoint"] for s in "lr"},
        **{f"{s}_knee": bones[f"{s}femur"] for s in "lr"},
        **{f"{s}_ankle": bones[f"{s}tibia"] for s in "lr"},
    }
    assert set(expected) == set(FULL_JOINTS)
    for joint, pts in expected.items():
        assert np.allclose(walk.positions_m[:, _j(joint)], pts), joint


def test_cmu_errors(tmp_path: Path, data_dir: Path) -> None:
    amc = tmp_path / "77_01.amc"
    amc.write_text((data_dir / "02_01.amc").read_text())
    with pytest.raises(RecordingError, match="77.asf"):
        load_recording(amc)
    (tmp_path / "77.asf").write_text((data_dir / "02.asf").read_text())
    lines = amc.read_text().splitlines()
    i = next(k for k, s in enumerate(lines) if s.startswith("lowerback"))
    bad = lines.copy()
    bad[i] = "lowerback 1.0 oops 2.0"
    amc.write_text("\n".join(bad))
    with pytest.raises(RecordingError, match="oops"):
        load_recording(amc)
    bad = lines.copy()
    del bad[i]
    amc.write_text("\n".join(bad))
    with pytest.raises(RecordingError, match="lowerback"):
        load_recording(amc)
    with pytest.raises(RecordingError, match="does not exist"):
        load_cmu(tmp_path / "nope.asf", amc)
    with pytest.raises(InputError, match="fps"):
        load_cmu(tmp_path / "77.asf", amc, fps=0.0)


# --- CSV -----------------------------------------------------------------------------------


def test_csv_round_trip_full(tmp_path: Path, walk: Recording) -> None:
    path = tmp_path / "walk.csv"
    save_csv(walk, path)
    header = path.read_text().splitlines()[0].split(",")
    assert header[:4] == ["time_s", "head_x", "head_y", "head_z"]
    assert len(header) == 1 + 3 * len(FULL_JOINTS)
    back = load_recording(path)
    assert back.kind == "full" and back.name == "walk"
    assert np.allclose(back.times_s, walk.times_s, rtol=0, atol=1e-9)
    assert np.allclose(back.positions_m, walk.positions_m, rtol=0, atol=1e-9)


def test_csv_round_trip_upper_and_column_order(tmp_path: Path) -> None:
    rec = _rec(5, "upper")
    path = tmp_path / "u.csv"
    save_csv(rec, path)
    back = load_csv(path)
    assert back.kind == "upper"
    assert np.array_equal(back.positions_m, rec.positions_m)
    # Columns in another order and an extra column are fine.
    header, *rows = [r.split(",") for r in path.read_text().splitlines()]
    perm = [0, *range(len(header) - 1, 0, -1)]
    lines = [[header[i] for i in perm] + ["note"]] + [[r[i] for i in perm] + ["x"] for r in rows]
    path.write_text("\n".join(",".join(r) for r in lines) + "\n")
    back = load_csv(path)
    assert np.array_equal(back.positions_m, rec.positions_m)


def _write(path: Path, header: list[str], rows: list[list[str]]) -> Path:
    path.write_text("\n".join(",".join(r) for r in [header, *rows]) + "\n")
    return path


def _upper_header() -> list[str]:
    return ["time_s"] + [f"{j}_{c}" for j in UPPER_JOINTS for c in "xyz"]


def _row(t: str) -> list[str]:
    return [t] + ["0.5"] * (3 * len(UPPER_JOINTS))


def test_csv_errors(tmp_path: Path) -> None:
    h = _upper_header()
    p = tmp_path / "bad.csv"
    # A missing joint column is named.
    _write(p, [c for c in h if c != "l_elbow_y"], [r[:-1] for r in [_row("0"), _row("1")]])
    with pytest.raises(RecordingError, match="l_elbow_y"):
        load_csv(p)
    # Some lower-body columns but not all: the missing ones are named.
    _write(p, [*h, "l_knee_x", "l_knee_y", "l_knee_z"], [_row("0") + ["1", "2", "3"]])
    with pytest.raises(RecordingError, match="r_ankle_z"):
        load_csv(p)
    # NaN is named with its line and column.
    bad = _row("0.1")
    bad[5] = "nan"
    _write(p, h, [_row("0"), bad])
    with pytest.raises(RecordingError, match=r"line 3 column 'neck_y'.*not finite"):
        load_csv(p)
    # Non-increasing time.
    _write(p, h, [_row("0"), _row("0.1"), _row("0.1")])
    with pytest.raises(RecordingError, match="time_s not strictly increasing"):
        load_csv(p)
    # Non-numeric value.
    bad = _row("0.1")
    bad[1] = "abc"
    _write(p, h, [_row("0"), bad])
    with pytest.raises(RecordingError, match=r"'head_x'.*'abc' is not a number"):
        load_csv(p)
    # Ragged row, missing time column, empty file, header only.
    _write(p, h, [_row("0"), _row("1")[:-2]])
    with pytest.raises(RecordingError, match="line 3"):
        load_csv(p)
    _write(p, h[1:], [_row("0")[1:]])
    with pytest.raises(RecordingError, match="time_s"):
        load_csv(p)
    p.write_text("")
    with pytest.raises(RecordingError, match="empty"):
        load_csv(p)
    _write(p, h, [])
    with pytest.raises(RecordingError, match="no data rows"):
        load_csv(p)
    # RecordingError is an InputError.
    with pytest.raises(InputError):
        load_csv(tmp_path / "missing.csv")


def test_a_csv_timed_in_milliseconds_is_refused(tmp_path: Path) -> None:
    """``time_s`` in milliseconds reads as motion a thousand times slower: a set fitted to it
    would be a thousand times too small. Frames further apart than 0.5 s or closer than 0.1 ms
    (median) are refused, naming the interval; a 2 Hz and a 10 kHz file are read."""
    h, p = _upper_header(), tmp_path / "t.csv"
    cases = ((["0", "16.7", "33.3"], False), (["0", "1", "2"], False),
             (["0", "0.5", "1.0"], True), (["0", "0.0001", "0.0002"], True),
             (["0", "1e-6", "2e-6"], False), (["0", "0.0167", "0.0333"], True))  # fmt: skip
    for times, ok in cases:
        _write(p, h, [_row(t) for t in times])
        if ok:
            assert load_csv(p).n_frames == 3
        else:
            with pytest.raises(RecordingError, match=r"frames are .* s apart.*milliseconds"):
                load_csv(p)


def test_load_recording_rejects_unknown_type(tmp_path: Path) -> None:
    p = tmp_path / "x.c3d"
    p.write_text("HIERARCHY\n")
    with pytest.raises(RecordingError, match=r"'\.c3d'.*\.amc, \.bvh, \.csv"):
        load_recording(p)
    bad = tmp_path / "x.bvh"
    bad.write_text("HIERARCHY\n")  # a known type that is malformed: said, never a traceback
    with pytest.raises(RecordingError, match="cannot read BVH file"):
        load_recording(bad)


# --- Recording and validate ----------------------------------------------------------------


def test_slice_and_frame_period() -> None:
    rec = _rec(10)
    s = rec.slice(2, 5)
    assert s.n_frames == 3 and np.array_equal(s.times_s, rec.times_s[2:5])
    assert np.array_equal(s.positions_m, rec.positions_m[2:5])
    assert s.frame_period_s == pytest.approx(0.1)
    assert rec.slice(-3, 10).n_frames == 3
    with pytest.raises(InputError, match="empty"):
        rec.slice(5, 5)
    with pytest.raises(InputError, match="frame period"):
        rec.slice(0, 1).frame_period_s  # noqa: B018


def test_validate_rejects_bad_arrays() -> None:
    good = _rec(4)
    validate(good)
    t, p = good.times_s, good.positions_m
    nan_p = p.copy()
    nan_p[2, 5, 1] = np.nan
    inf_t = t.copy()
    inf_t[1] = np.inf
    cases: list[tuple[dict[str, Any], str]] = [
        (dict(kind="lower"), "unknown skeleton kind 'lower'"),
        (dict(positions_m=nan_p), r"joint 'l_elbow' \(y\) at frame 2"),
        (dict(times_s=inf_t), r"times_s\[1\] = inf"),
        (dict(times_s=t[::-1].copy()), "not strictly increasing"),
        (dict(times_s=np.array([0.0, 0.1, 0.1, 0.2])), "not strictly increasing"),
        (dict(positions_m=p[:, :9]), r"expected \(4, 15, 3\)"),
        (dict(positions_m=p[:3]), r"expected \(4, 15, 3\)"),
        (dict(kind="upper"), r"expected \(4, 9, 3\)"),
        (dict(times_s=t[:, None]), r"expected \(T,\)"),
        (dict(times_s=np.zeros(0), positions_m=np.zeros((0, 15, 3))), "T >= 1"),
    ]
    base: dict[str, Any] = dict(name="bad", kind="full", times_s=t, positions_m=p, source="")
    for change, msg in cases:
        fields = {**base, **change}
        with pytest.raises(InputError, match=msg):
            validate(SimpleNamespace(**fields))  # type: ignore[arg-type]
        with pytest.raises(InputError, match=msg):
            Recording(**fields)  # type: ignore[arg-type]


def test_the_package_looks_for_no_data_folder_but_sara_data_dir(monkeypatch, tmp_path) -> None:
    """Without SARA_DATA_DIR nothing beside the repository is searched (../shared may be there
    on this machine); the recordings the shipped scenarios use load from the package."""
    from sara_app.errors import RecordingError

    monkeypatch.delenv("SARA_DATA_DIR", raising=False)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(RecordingError, match="SARA_DATA_DIR"):
        shared_data_dir()
    with pytest.raises(
        RecordingError, match="no recording named '09_06'.*SARA_DATA_DIR is not set"
    ):
        load_recording("09_06")  # the run: not shipped
    from sara_app.human.recordings import find_recording

    for name in ("02_01", "62_07", "HumanRobotHandover/0"):
        path = find_recording(name)
        assert "sara_app" in path.parts and "shared" not in path.parts, path
        assert load_recording(name).n_frames > 100
