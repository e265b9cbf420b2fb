"""BVH recordings (sara_app.human.bvh): the joint maps, units and up axis established from the
data, a T-pose first frame, against files written here whose joint positions are known by hand
(the oracle: offsets summed, one root rotation), and on the given recordings when present."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from sara_app.errors import InputError, RecordingError
from sara_app.human.bvh import UNITS, load_bvh, to_z_up
from sara_app.human.recordings import load_recording
from sara_app.human.skeleton import FULL_JOINTS, UPPER_JOINTS

# A CMU-named skeleton in centimetres, y up, standing: name -> (parent, offset)
CMU_CM = {
    "Hips": (None, (0, 0, 0)),  # the root's place is its position channels
    "LHipJoint": ("Hips", (0, 0, 0)),
    "LeftUpLeg": ("LHipJoint", (10, -5, 0)),
    "LeftLeg": ("LeftUpLeg", (0, -45, 0)),
    "LeftFoot": ("LeftLeg", (0, -45, 0)),
    "RHipJoint": ("Hips", (0, 0, 0)),
    "RightUpLeg": ("RHipJoint", (-10, -5, 0)),
    "RightLeg": ("RightUpLeg", (0, -45, 0)),
    "RightFoot": ("RightLeg", (0, -45, 0)),
    "Spine": ("Hips", (0, 25, 0)),
    "Neck": ("Spine", (0, 25, 0)),
    "Head": ("Neck", (0, 15, 0)),
    "LeftArm": ("Neck", (18, -2, 0)),
    "LeftForeArm": ("LeftArm", (0, -30, 0)),
    "LeftHand": ("LeftForeArm", (0, -25, 0)),
    "RightArm": ("Neck", (-18, -2, 0)),
    "RightForeArm": ("RightArm", (0, -30, 0)),
    "RightHand": ("RightForeArm", (0, -25, 0)),
}
HEAD_END = (0, 20, 0)


def _write_bvh(path: Path, joints: dict, end: dict, frames: list[list[float]], dt: float) -> Path:
    children: dict = {n: [] for n in joints}
    for n, (parent, _) in joints.items():
        if parent is not None:
            children[parent].append(n)
    lines = ["HIERARCHY"]

    def emit(n: str, depth: int) -> None:
        pad = "  " * depth
        parent, off = joints[n]
        lines.append(f"{pad}{'ROOT' if parent is None else 'JOINT'} {n}")
        lines.append(pad + "{")
        lines.append(f"{pad}  OFFSET {' '.join(str(float(x)) for x in off)}")
        chans = "Xposition Yposition Zposition " if parent is None else ""
        lines.append(f"{pad}  CHANNELS {6 if parent is None else 3} {chans}Zrotation Xrotation "
                     "Yrotation")  # fmt: skip
        for c in children[n]:
            emit(c, depth + 1)
        if not children[n]:
            e = end.get(n, (0, 0, 0))
            off_e = " ".join(str(float(x)) for x in e)
            lines.extend([f"{pad}  End Site", pad + "  {", f"{pad}    OFFSET {off_e}", pad + "  }"])
        lines.append(pad + "}")

    emit(next(iter(joints)), 0)
    lines += ["MOTION", f"Frames: {len(frames)}", f"Frame Time: {dt}"]
    lines += [" ".join(str(float(v)) for v in f) for f in frames]
    path.write_text("\n".join(lines) + "\n")
    return path


def _rest(joints: dict) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for n, (parent, off) in joints.items():
        out[n] = (np.zeros(3) if parent is None else out[parent]) + np.asarray(off, float)
    return out


def _frame(root_xyz: tuple[float, float, float], yrot_deg: float, n_joints: int) -> list[float]:
    return [*root_xyz, 0.0, 0.0, yrot_deg] + [0.0] * (3 * (n_joints - 1))


def test_a_cmu_skeleton_in_cm_y_up_maps_to_the_project_joints_in_metres_z_up(
    tmp_path: Path,
) -> None:
    n = len(CMU_CM)
    frames = [_frame((5.0 * k, 100.0, 0.0), 0.0, n) for k in range(4)]
    rec = load_bvh(_write_bvh(tmp_path / "walk.bvh", CMU_CM, {"Head": HEAD_END}, frames, 0.01))
    assert rec.kind == "full" and "unit cm" in rec.source and "up +y" in rec.source
    rest = _rest(CMU_CM)
    points = {
        "head": (rest["Head"] + rest["Head"] + np.asarray(HEAD_END)) / 2, "neck": rest["Neck"],
        "pelvis": rest["Hips"], "l_shoulder": rest["LeftArm"], "r_shoulder": rest["RightArm"],
        "l_elbow": rest["LeftForeArm"], "r_elbow": rest["RightForeArm"],
        "l_wrist": rest["LeftHand"], "r_wrist": rest["RightHand"], "l_hip": rest["LeftUpLeg"],
        "r_hip": rest["RightUpLeg"], "l_knee": rest["LeftLeg"], "r_knee": rest["RightLeg"],
        "l_ankle": rest["LeftFoot"], "r_ankle": rest["RightFoot"],
    }  # fmt: skip
    for k in range(4):
        for j, name in enumerate(FULL_JOINTS):
            x, y, z = (points[name] + [5.0 * k, 0.0, 0.0] + [0.0, 100.0, 0.0]) * 0.01
            np.testing.assert_allclose(rec.positions_m[k, j], [x, -z, y], atol=1e-9)
    np.testing.assert_allclose(rec.times_s, [0.0, 0.01, 0.02, 0.03])
    # left stays left: facing -y_world (the file's +z), the person's left is +x
    assert rec.positions_m[0, FULL_JOINTS.index("l_shoulder"), 0] > 0


def test_a_root_rotation_turns_the_person_about_the_up_axis(tmp_path: Path) -> None:
    n = len(CMU_CM)
    frames = [_frame((0.0, 0.0, 0.0), 0.0, n), _frame((0.0, 0.0, 0.0), 90.0, n)] * 2
    rec = load_bvh(_write_bvh(tmp_path / "turn.bvh", CMU_CM, {"Head": HEAD_END}, frames, 0.01))
    i = FULL_JOINTS.index("l_shoulder")
    a, b = rec.positions_m[0, i], rec.positions_m[1, i]
    assert math.isclose(a[2], b[2], abs_tol=1e-9)  # height kept
    assert math.isclose(np.hypot(*a[:2]), np.hypot(*b[:2]), rel_tol=1e-9)  # about the up axis
    assert abs(a[0] - b[0]) > 0.1  # and turned


def test_units_and_up_axis_can_be_given_and_are_checked(tmp_path: Path) -> None:
    n = len(CMU_CM)
    path = _write_bvh(tmp_path / "x.bvh", CMU_CM, {"Head": HEAD_END}, [_frame((0, 0, 0), 0, n)] * 3,
                      0.01)  # fmt: skip
    as_mm = load_bvh(path, unit="mm")
    as_cm = load_bvh(path)
    np.testing.assert_allclose(as_mm.positions_m * 10, as_cm.positions_m, atol=1e-12)
    with pytest.raises(InputError, match="valid: m, cm, mm"):
        load_bvh(path, unit="furlong")
    with pytest.raises(InputError, match="valid: \\+x"):
        load_bvh(path, up="up")
    for axis in ("+x", "-x", "+y", "-y", "+z", "-z"):
        R = to_z_up(axis)
        assert math.isclose(np.linalg.det(R), 1.0) and np.allclose(R @ R.T, np.eye(3))
        k, s = "xyz".index(axis[1]), 1.0 if axis[0] == "+" else -1.0
        np.testing.assert_allclose(R @ (s * np.eye(3)[k]), [0, 0, 1], atol=1e-12)


def test_a_skeleton_of_no_plausible_size_is_refused(tmp_path: Path) -> None:
    giant = {k: (p, tuple(100.0 * x for x in off)) for k, (p, off) in CMU_CM.items()}
    n = len(giant)
    path = _write_bvh(tmp_path / "g.bvh", giant, {"Head": HEAD_END}, [_frame((0, 0, 0), 0, n)] * 3,
                      0.01)  # fmt: skip
    with pytest.raises(RecordingError, match="no unit makes the upper arm"):
        load_bvh(path)
    assert load_bvh(path, unit="mm").kind == "full"  # the user's word


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize("channel, first", [(1, "Hips"), (5, "LHipJoint")])
def test_a_non_finite_channel_is_refused_naming_its_frame(
    tmp_path: Path, value: float, channel: int, first: str
) -> None:
    """A corrupt channel (the root's Y position, or its Y rotation, which moves every joint
    below it) is refused with the frame and the first joint it misplaces, before the unit and up
    axis are guessed from it (it was refused as a skeleton of no plausible size)."""
    n = len(CMU_CM)
    frames = [_frame((0, 90, 0), 0, n) for _ in range(4)]
    frames[2][channel] = value
    path = _write_bvh(tmp_path / "c.bvh", CMU_CM, {"Head": HEAD_END}, frames, 0.01)
    with pytest.raises(RecordingError, match=rf"frame 2 puts '{first}' at a non-finite position "
                       r"\(1 of 4 frames"):  # fmt: skip
        load_bvh(path)
    assert load_bvh(_write_bvh(tmp_path / "ok.bvh", CMU_CM, {"Head": HEAD_END},
                               [_frame((0, 90, 0), 0, n)] * 4, 0.01)).kind == "full"  # fmt: skip


@pytest.mark.parametrize("dt, ok", [(8.333, False), (1.0, False), (1e-9, False), (0.5, True),
                                    (1e-4, True), (0.0083333, True)])  # fmt: skip
def test_a_frame_time_no_tracker_has_is_refused(tmp_path: Path, dt: float, ok: bool) -> None:
    """A Frame Time in milliseconds (8.333 for 120 Hz) read as motion a thousand times slower
    (a set fitted to it a thousand times too small); one of a nanosecond put every frame within
    one horizon and `reach` did not end. Outside 0.1 ms to 0.5 s: refused, naming it."""
    n = len(CMU_CM)
    path = _write_bvh(tmp_path / "t.bvh", CMU_CM, {"Head": HEAD_END},
                      [_frame((0, 90, 0), 0, n)] * 4, dt)  # fmt: skip
    if ok:
        assert load_bvh(path).times_s[1] == pytest.approx(dt, rel=1e-3)  # 120 Hz: snapped
    else:
        with pytest.raises(RecordingError, match=r"frames are .* s apart.*Frame Time in seconds"):
            load_bvh(path)


def test_a_t_pose_first_frame_is_dropped(tmp_path: Path) -> None:
    tpose = dict(CMU_CM)
    n = len(tpose)
    # frame 0: arms out sideways (shoulder joints rotated 90 degrees about z), then hanging
    names = list(tpose)
    f0 = _frame((0, 0, 0), 0, n)
    for side, sign in (("LeftArm", 1.0), ("RightArm", -1.0)):
        f0[3 + 3 * names.index(side)] = sign * 90.0  # Zrotation of that joint
    frames = [f0] + [_frame((0, 0, 0), 0, n)] * 3
    rec = load_bvh(_write_bvh(tmp_path / "t.bvh", tpose, {"Head": HEAD_END}, frames, 0.01))
    assert len(rec.times_s) == 3 and "T-pose frame 0 dropped" in rec.source


def test_the_vicon_upper_body_skeleton_is_an_upper_recording(tmp_path: Path) -> None:
    vicon = {
        "hip": (None, (0, 0, 0)), "torso": ("hip", (0, 0, 0)), "neck": ("torso", (0, 450, 0)),
        "head": ("neck", (0, 300, 0)), "left_collar": ("torso", (0, 450, 0)),
        "left_upper_arm": ("left_collar", (180, 0, 0)), "left_forearm": ("left_upper_arm",
        (0, -300, 0)), "left_hand": ("left_forearm", (0, -250, 0)),
        "right_collar": ("torso", (0, 450, 0)), "right_upper_arm": ("right_collar", (-180, 0, 0)),
        "right_forearm": ("right_upper_arm", (0, -300, 0)),
        "right_hand": ("right_forearm", (0, -250, 0)),
    }  # fmt: skip
    n = len(vicon)
    rec = load_bvh(_write_bvh(tmp_path / "v.bvh", vicon, {}, [_frame((0, 900, 0), 0, n)] * 3, 0.01))
    assert rec.kind == "upper" and rec.positions_m.shape == (3, len(UPPER_JOINTS), 3)
    assert "unit mm" in rec.source
    head, neck = rec.positions_m[0, 0], rec.positions_m[0, 1]
    np.testing.assert_allclose(head - neck, [0, 0, 0.15], atol=1e-12)  # the head's centre


def test_an_unknown_skeleton_names_what_is_missing(tmp_path: Path) -> None:
    odd = {"root": (None, (0, 0, 0)), "a": ("root", (0, 10, 0))}
    path = _write_bvh(tmp_path / "o.bvh", odd, {}, [_frame((0, 0, 0), 0, 2)] * 3, 0.01)
    with pytest.raises(RecordingError, match="none of the known ones"):
        load_bvh(path)


def _shared_bvh() -> list[Path]:
    import os

    base = Path(os.environ.get("SARA_DATA_DIR", Path(__file__).resolve().parents[2] / "shared"))
    for cand in (base / "data", base, base.parent):
        files = sorted(cand.glob("cmu62_bvh/*.bvh")) + sorted(cand.glob("tum_hrc_bvh/*/*.bvh"))
        if files:
            return files
    return []


@pytest.mark.skipif(not _shared_bvh(), reason="the BVH recordings are not here (SARA_DATA_DIR)")
def test_the_given_recordings_load_with_rigid_bones_upright_and_in_metres() -> None:
    for path in _shared_bvh():
        rec = load_recording(path)
        y = rec.positions_m
        i = {j: k for k, j in enumerate(FULL_JOINTS)}
        for s in "lr":  # rigid bones: the forward kinematics is consistent
            ua = np.linalg.norm(y[:, i[f"{s}_elbow"]] - y[:, i[f"{s}_shoulder"]], axis=1)
            fa = np.linalg.norm(y[:, i[f"{s}_wrist"]] - y[:, i[f"{s}_elbow"]], axis=1)
            assert np.ptp(ua) < 1e-6 and np.ptp(fa) < 1e-6, path
            assert 0.2 < ua[0] < 0.45 and 0.15 < fa[0] < 0.35, (path, ua[0], fa[0])
        up = y[:, i["neck"], 2] - y[:, i["pelvis"], 2]
        assert np.median(up) > 0.1, path  # upright (z up) on the whole
        assert rec.kind == ("full" if "cmu62" in str(path) else "upper")
        assert set(UNITS) >= {rec.source.split("unit ")[1].split()[0]}


@pytest.mark.parametrize("left_x", [180.0, -180.0])
def test_left_handed_axes_are_mirrored_so_that_left_stays_left(
    tmp_path: Path, left_x: float
) -> None:
    """Head 0.1 m in front of the neck in the rest pose (+z): in right-handed y-up axes the left
    shoulder is at +x; at -x the file's axes are left-handed and the recording is mirrored."""
    vicon = {
        "hip": (None, (0, 0, 0)), "torso": ("hip", (0, 0, 0)), "neck": ("torso", (0, 450, 0)),
        "head": ("neck", (0, 300, 100)), "left_collar": ("torso", (0, 450, 0)),
        "left_upper_arm": ("left_collar", (left_x, 0, 0)),
        "left_forearm": ("left_upper_arm", (0, -300, 0)),
        "left_hand": ("left_forearm", (0, -250, 0)), "right_collar": ("torso", (0, 450, 0)),
        "right_upper_arm": ("right_collar", (-left_x, 0, 0)),
        "right_forearm": ("right_upper_arm", (0, -300, 0)),
        "right_hand": ("right_forearm", (0, -250, 0)),
    }  # fmt: skip
    n = len(vicon)
    rec = load_bvh(_write_bvh(tmp_path / "h.bvh", vicon, {}, [_frame((0, 900, 0), 0, n)] * 3, 0.01))
    y = rec.positions_m[0]
    i = {j: k for k, j in enumerate(UPPER_JOINTS)}
    forward = y[i["head"]] - y[i["neck"]]
    forward[2] = 0.0
    left = y[i["l_shoulder"]] - y[i["r_shoulder"]]
    assert np.cross([0, 0, 1], forward) @ left > 0  # left of (up, forward), either way
    assert ("mirrored" in rec.source) == (left_x < 0)
