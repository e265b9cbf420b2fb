"""Bone lengths no person has (``sara_app.human.anatomy``, checked by the tracking gate; the
compiled check against the numpy oracle is ``tests/test_gate_kernels.py``): every recording
within the ranges, a skeleton collapsed to a point never trusted."""

from __future__ import annotations

import glob
import os

import numpy as np
import pytest

from sara_app.human.anatomy import BONE_RANGE_M, bone_ranges
from sara_app.human.gate import FLAGS, bone_indices
from sara_app.human.intake import Intake
from sara_app.human.recordings import PACKAGED_DATA_DIR, load_recording
from sara_app.human.skeleton import FULL_JOINTS, skeleton
from sara_app.human.tracking_settings import BONES

DY = 0.004
STANDING = np.array(
    [
        (0, 0, 1.65), (0, 0, 1.45), (0, 0, 0.95), (0, 0.18, 1.42), (0, -0.18, 1.42),
        (0, 0.22, 1.15), (0, -0.22, 1.15), (0, 0.24, 0.9), (0, -0.24, 0.9), (0, 0.1, 0.92),
        (0, -0.1, 0.92), (0, 0.1, 0.5), (0, -0.1, 0.5), (0, 0.1, 0.08), (0, -0.1, 0.08),
    ]
)  # fmt: skip


def test_every_bone_has_a_range() -> None:
    assert set(BONE_RANGE_M) == set(BONES)
    assert all(0 < lo < hi < 1.0 for lo, hi in BONE_RANGE_M.values())


def test_a_point_is_no_person_from_the_first_frame() -> None:
    """All joints within a millimetre of one point: every bone is outside a person's range,
    every joint is held with no history (unbounded sets) and no bone length is learned."""
    intake = Intake(DY, np.full(15, 2.0), np.full(15, 50.0))
    rng = np.random.default_rng(1)
    for k in range(20):
        point = np.tile([1.3, 0.0, 1.0], (15, 1)) + rng.normal(scale=0.001, size=(15, 3))
        taken = intake.take(0.01 * (k + 1), point, DY, 15)
        g = intake.gate.out
        assert not g.trusted.any() and g.flags[:, FLAGS.index("bone")].all()
        assert taken is None or np.isinf(g.extra_m).all()
    assert np.isnan(intake.gate.length_m).all()
    assert intake.gate.counts["bone"] >= 15 * 10


def test_a_standing_person_is_one_and_a_stretched_arm_is_blamed_on_its_jump() -> None:
    intake = Intake(DY, np.full(15, 2.0), np.full(15, 50.0))
    rng = np.random.default_rng(2)
    for k in range(10):
        assert intake.take(0.01 * (k + 1), STANDING + rng.normal(scale=0.001, size=(15, 3)),
                           DY, 15) is not None  # fmt: skip
        assert intake.gate.out.trusted.all()
    y = STANDING + rng.normal(scale=0.001, size=(15, 3))
    wrist = FULL_JOINTS.index("l_wrist")
    y[wrist] += [0.0, 0.0, 0.45]  # a forearm of 0.7 m: the wrist jumped there
    intake.take(0.11, y, DY, 15)
    held = ~intake.gate.out.trusted
    assert held[wrist] and held.sum() == 1


def test_unmeasured_and_lost_joints_are_not_judged() -> None:
    up = STANDING.copy()
    up[9:] = up[2]  # an upper-body source: the legs at the pelvis, not measured
    intake = Intake(DY, np.full(15, 2.0), np.full(15, 50.0))
    assert intake.take(0.01, up, DY, 9) is not None and intake.gate.out.trusted.all()


def _recordings() -> list[str]:
    files = sorted(glob.glob(str(PACKAGED_DATA_DIR / "**" / "*.*"), recursive=True))
    shared = os.environ.get("SARA_DATA_DIR")
    if shared:
        files += sorted(glob.glob(os.path.join(shared, "data", "**", "*.*"), recursive=True))
    return [f for f in files if f.lower().endswith((".bvh", ".amc", ".csv"))]


@pytest.mark.parametrize("path", _recordings(), ids=os.path.basename)
def test_every_frame_of_every_recording_is_a_persons(path: str) -> None:
    """The ranges hold every frame of the recordings, reconstruction failures included (the
    packaged ones always, the data folder's with ``SARA_DATA_DIR``)."""
    rec = load_recording(path)
    n = len(skeleton(rec.kind).joints)
    bones = bone_indices()
    bones = bones[(bones < n).all(axis=1)]
    lo, hi = bone_ranges(bones, FULL_JOINTS)
    y = rec.positions_m
    length = np.linalg.norm(y[:, bones[:, 0]] - y[:, bones[:, 1]], axis=-1)  # (T, B)
    assert (length >= lo).all() and (length <= hi).all()  # without the noise's allowance
