"""Bone lengths no person has: the compiled check against a numpy oracle, every recording
within the ranges, and a degenerate skeleton refused as a measurement."""

from __future__ import annotations

import glob
import os

import numpy as np
import pytest

from sara_app.human.anatomy import BONE_RANGE_M, bone_ranges, implausible_bone
from sara_app.human.gate import BONES, bone_indices
from sara_app.human.intake import Intake
from sara_app.human.recordings import PACKAGED_DATA_DIR, load_recording
from sara_app.human.skeleton import FULL_JOINTS, full_body, skeleton

DY = 0.004
STANDING = np.array(
    [
        (0, 0, 1.65), (0, 0, 1.45), (0, 0, 0.95), (0, 0.18, 1.42), (0, -0.18, 1.42),
        (0, 0.22, 1.15), (0, -0.22, 1.15), (0, 0.24, 0.9), (0, -0.24, 0.9), (0, 0.1, 0.92),
        (0, -0.1, 0.92), (0, 0.1, 0.5), (0, -0.1, 0.5), (0, 0.1, 0.08), (0, -0.1, 0.08),
    ]
)  # fmt: skip


def _oracle(y, n_measured, lost, bones, lo, hi, slack) -> int:
    for k, (a, b) in enumerate(bones):
        if a >= n_measured or b >= n_measured or lost[a] or lost[b]:
            continue
        length = np.linalg.norm(y[a] - y[b])
        if not (lo[k] - slack <= length <= hi[k] + slack):
            return k
    return -1


def test_every_bone_has_a_range() -> None:
    assert set(BONE_RANGE_M) == set(BONES)
    assert all(0 < lo < hi < 1.0 for lo, hi in BONE_RANGE_M.values())


def test_the_kernel_agrees_with_the_oracle() -> None:
    rng = np.random.default_rng(0)
    bones = bone_indices()
    lo, hi = bone_ranges(bones, FULL_JOINTS)
    found = set()
    for _ in range(3000):
        y = STANDING + rng.normal(scale=rng.choice([0.01, 0.1, 0.3]), size=STANDING.shape)
        if rng.random() < 0.05:
            y[rng.integers(15)] = np.nan
        n = int(rng.choice([9, 15]))
        lost = rng.random(15) < 0.1
        slack = float(rng.uniform(0, 0.1))
        want = _oracle(y, n, lost, bones, lo, hi, slack)
        assert implausible_bone(y, n, lost, bones, lo, hi, slack) == want
        found.add(want >= 0)
    assert found == {True, False}


def test_a_standing_person_passes_and_a_point_does_not() -> None:
    intake = Intake(DY, np.full(15, 2.0), np.full(15, 50.0))
    assert intake.gate.implausible(STANDING, DY, 15, None) is None
    rng = np.random.default_rng(1)
    for k in range(20):  # never taken: no bone lengths are learned from it
        point = np.tile([1.3, 0.0, 1.0], (15, 1)) + rng.normal(scale=0.001, size=(15, 3))
        assert intake.take(0.01 * (k + 1), point, DY, 15) is None
        assert intake.refusal == "tracking_inconsistent"
    fault = intake.fault("p")
    assert fault is not None and "bone " in fault and "not a person's" in fault
    assert intake.gate.counts["refused"] == 20
    assert intake.take(0.5, STANDING, DY, 15) is not None  # a body again: taken
    assert intake.fault("p") is None


def test_unmeasured_and_lost_joints_are_not_judged() -> None:
    up = STANDING.copy()
    up[9:] = up[2]  # an upper-body source: the legs at the pelvis, not measured
    intake = Intake(DY, np.full(15, 2.0), np.full(15, 50.0))
    assert intake.gate.implausible(up, DY, 9, None) is None
    assert intake.gate.implausible(up, DY, 15, None) is not None
    lost = np.zeros(15, bool)
    lost[9:] = True
    assert intake.gate.implausible(up, DY, 15, lost) is None


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
    none = np.zeros(15, bool)
    for y in rec.positions_m:
        yf, _ = full_body(y, None)
        assert implausible_bone(yf, n, none, bones, lo, hi, 0.0) == -1  # without the noise
