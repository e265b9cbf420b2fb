"""Body trackers' layouts (Azure Kinect, BlazePose, ZED BODY_34): a recorded-style frame of each
decodes to the pose it was made from (units included); confidences map to missing and low
joints; a real cell worker holds a missing joint at its last position with growing sets, widens
a low-confidence one, refuses a frame whose missing joint it never saw, and counts it all."""

from __future__ import annotations

import time

import numpy as np
import pytest
from pydantic import ValidationError

from sara_app.bus.messages import SkeletonMsg
from sara_app.bus.session import Bus, free_port
from sara_app.human.reach import MODELS
from sara_app.human.skeleton import FULL_JOINTS, skeleton
from sara_app.human.trackers import (
    AZURE_KINECT_JOINTS,
    BLAZEPOSE_LANDMARKS,
    ZED_BODY34_KEYPOINTS,
    ZED_BODY38_KEYPOINTS,
)
from sara_app.runtime.worker import CellWorker
from sara_app.scenario import load_scenario

STANDING = {
    "head": (1.4, 0.0, 1.65), "neck": (1.4, 0.0, 1.45), "pelvis": (1.4, 0.0, 0.95),
    "l_shoulder": (1.4, 0.18, 1.42), "r_shoulder": (1.4, -0.18, 1.42),
    "l_elbow": (1.4, 0.22, 1.15), "r_elbow": (1.4, -0.22, 1.15),
    "l_wrist": (1.4, 0.24, 0.9), "r_wrist": (1.4, -0.24, 0.9),
    "l_hip": (1.4, 0.1, 0.92), "r_hip": (1.4, -0.1, 0.92),
    "l_knee": (1.4, 0.1, 0.5), "r_knee": (1.4, -0.1, 0.5),
    "l_ankle": (1.4, 0.1, 0.08), "r_ankle": (1.4, -0.1, 0.08),
}  # fmt: skip
Y = np.array([STANDING[j] for j in FULL_JOINTS])
SIDE = {"l": "left", "r": "right"}


def _near(p: np.ndarray, rng: np.random.Generator) -> list[float]:
    return (p + rng.normal(scale=0.05, size=3)).tolist()


def azure_frame(y: np.ndarray, rng: np.random.Generator) -> dict[str, list[float]]:
    """All 32 K4ABT joints in millimetres: the mapped ones at the pose, the others near it."""
    out = {}
    for name in AZURE_KINECT_JOINTS:
        part, *side = name.split("_")
        j = {"head": "head", "neck": "neck", "pelvis": "pelvis"}.get(name)
        if (
            j is None
            and side
            and side[0] in ("left", "right")
            and part in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")
        ):
            j = f"{side[0][0]}_{part}"
        p = y[FULL_JOINTS.index(j)] if j else np.array(_near(y[1], rng))
        out[name] = (1000.0 * np.asarray(p)).tolist()
    return out


def blazepose_frame(y: np.ndarray, rng: np.random.Generator) -> dict[str, list[float]]:
    """All 33 landmarks in metres; the ears either side of the head centre."""
    out = {n: _near(y[0], rng) for n in BLAZEPOSE_LANDMARKS}
    for s, side in SIDE.items():
        for j in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle"):
            out[f"{side}_{j}"] = y[FULL_JOINTS.index(f"{s}_{j}")].tolist()
    off = np.array([0.0, 0.08, 0.0])
    out["left_ear"], out["right_ear"] = (y[0] + off).tolist(), (y[0] - off).tolist()
    return out


def _zed(names: tuple[str, ...], y: np.ndarray, rng: np.random.Generator) -> dict[str, list]:
    """A ZED frame: the mapped keypoints at the pose (the ears either side of the head centre,
    as BODY_38 has no head keypoint), the others near the neck."""
    out = {n: _near(y[1], rng) for n in names}
    for j in ("head", "neck", "pelvis"):
        out[j] = y[FULL_JOINTS.index(j)].tolist()
    for s, side in SIDE.items():
        for j in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle"):
            out[f"{side}_{j}"] = y[FULL_JOINTS.index(f"{s}_{j}")].tolist()
    off = np.array([0.0, 0.08, 0.0])
    out["left_ear"], out["right_ear"] = (y[0] + off).tolist(), (y[0] - off).tolist()
    if "head" not in names:
        del out["head"]
    return out


def zed_frame(y: np.ndarray, rng: np.random.Generator) -> dict[str, list[float]]:
    return _zed(ZED_BODY34_KEYPOINTS, y, rng)


def zed38_frame(y: np.ndarray, rng: np.random.Generator) -> dict[str, list[float]]:
    return _zed(ZED_BODY38_KEYPOINTS, y, rng)


FRAMES = {"azure_kinect": azure_frame, "blazepose": blazepose_frame, "zed_body34": zed_frame,
          "zed_body38": zed38_frame}  # fmt: skip


@pytest.mark.parametrize("source", sorted(FRAMES))
def test_each_layout_decodes_to_the_pose(source: str) -> None:
    rng = np.random.default_rng(2)
    msg = SkeletonMsg(seq=1, stamp_s=1.0, source=source, joints=FRAMES[source](Y, rng))
    y, v = msg.to_arrays()
    assert msg.kind == "full" and v is None
    want = Y.copy()
    if source == "blazepose":  # no neck or pelvis landmark: the shoulders' and hips' midpoints
        want[1] = Y[[3, 4]].mean(axis=0)
        want[2] = Y[[9, 10]].mean(axis=0)
    np.testing.assert_allclose(y, want, atol=1e-9)
    missing, low = msg.joint_states()
    assert not missing.any() and not low.any()
    with pytest.raises(ValidationError, match="needs"):  # without confidences: every point
        SkeletonMsg(seq=1, stamp_s=1.0, source=source,
                    joints={k: p for k, p in FRAMES[source](Y, rng).items() if k != "neck"
                            and k != "left_shoulder"})  # fmt: skip


def test_confidences_map_to_missing_and_low_joints() -> None:
    rng = np.random.default_rng(3)
    i = FULL_JOINTS.index
    frame = azure_frame(Y, rng)
    conf = dict.fromkeys(AZURE_KINECT_JOINTS, 2.0)
    conf["wrist_left"], conf["knee_right"] = 1.0, 0.0  # LOW, NONE
    msg = SkeletonMsg(seq=1, stamp_s=1.0, source="azure_kinect", joints=frame, confidence=conf)
    missing, low = msg.joint_states()
    assert np.flatnonzero(missing).tolist() == [i("r_knee")]
    assert np.flatnonzero(low).tolist() == [i("l_wrist")]
    # a point left out of a message with confidences is missing; its joint's row is NaN
    frame = blazepose_frame(Y, rng)
    del frame["right_ear"]
    vis = dict.fromkeys(BLAZEPOSE_LANDMARKS, 0.9)
    vis["left_hip"] = 0.3  # low visibility: the pelvis (mean of the hips) is low
    msg = SkeletonMsg(seq=1, stamp_s=1.0, source="blazepose", joints=frame, confidence=vis)
    missing, low = msg.joint_states()
    assert np.flatnonzero(missing).tolist() == [i("head")]
    assert set(np.flatnonzero(low).tolist()) == {i("pelvis"), i("l_hip")}
    y, _ = msg.to_arrays()
    assert np.isnan(y[i("head")]).all() and np.isfinite(np.delete(y, i("head"), 0)).all()
    with pytest.raises(ValidationError, match="not points of source"):
        SkeletonMsg(seq=1, stamp_s=1.0, source="zed_body34", joints=zed_frame(Y, rng),
                    confidence={"tail": 50.0})  # fmt: skip


def test_a_worker_holds_missing_joints_and_widens_low_ones() -> None:
    """A real cell worker (its own zenoh session) ingests ZED frames of a standing person."""
    port = free_port()
    rng = np.random.default_rng(4)
    i = FULL_JOINTS.index
    with Bus.router(port), Bus.client(port) as bus:
        worker = CellWorker("trk", load_scenario("standing_beside_path"), bus)
        conf = dict.fromkeys(ZED_BODY34_KEYPOINTS, 90.0)
        t0 = time.time()

        def frame(k: int, **c: float) -> SkeletonMsg:
            y = Y + rng.normal(scale=0.001, size=Y.shape)
            return SkeletonMsg(seq=k, stamp_s=t0 + k / 30, source="zed_body34",
                               joints=zed_frame(y, rng), confidence={**conf, **c})  # fmt: skip

        # never seen: a frame whose left wrist is missing is refused (nothing to hold)
        worker.people.take_skeleton("p1", frame(0, left_wrist=0.0), time.time())
        assert worker.presence.tracks["p1"].state.stamp_s is None
        for k in range(1, 20):  # clean frames: the wrist is known
            worker.people.take_skeleton("p1", frame(k), time.time())
        track = worker.presence.tracks["p1"]
        last_wrist = track.state.y[i("l_wrist")].copy()
        for k in range(20, 26):  # the wrist missing for 0.2 s: held and widened with time
            worker.people.take_skeleton("p1", frame(k, left_wrist=0.0), time.time())
            np.testing.assert_array_equal(track.state.y[i("l_wrist")], last_wrist)
            assert track.state.stamp_s == pytest.approx(t0 + k / 30)
        w = track.state.widen_m
        assert w is not None
        hand = skeleton("full").part_index("l_hand")
        v_max = worker.cell.params.v_max_mps[i("l_wrist")]
        assert w[MODELS.index("vel"), hand] >= v_max * 5 / 30 - 1e-9  # grown since trusted
        assert np.isinf(track.state.dv[i("l_wrist")])  # no velocity from a held joint
        counts = track.intake.counts()
        assert counts["missing"] == 1 + 6  # the refused first frame is counted too
        # back, but low confidence: trusted again, widened by the scenario's extra
        worker.people.take_skeleton("p1", frame(26, left_wrist=30.0), time.time())
        extra = worker.cell.scenario.inputs.low_confidence_extra_m
        w = track.state.widen_m
        assert w is not None and w[MODELS.index("vel"), hand] == pytest.approx(extra)
        assert w[MODELS.index("vel"), skeleton("full").part_index("r_hand")] == 0.0
        # missing too long (max_hold_s): refused, the person ages (counted)
        before = worker.io.decoder.counts.get("tracking_inconsistent", 0)
        for k in range(27, 50):
            worker.people.take_skeleton("p1", frame(k, right_ankle=5.0), time.time())
        assert worker.io.decoder.counts.get("tracking_inconsistent", 0) > before
        assert track.state.stamp_s < t0 + 49 / 30
