"""Simulated people (sara_app.sim.motions): an upper-body recording replays on standing legs, and
its simulated sensor measures the upper body only, as an upper-body tracker would."""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.human.recording import Recording
from sara_app.human.recordings import load_recording
from sara_app.human.scripted import STANDING_LEGS_M
from sara_app.human.skeleton import FULL_JOINTS, UPPER_JOINTS
from sara_app.scenario import load_scenario
from sara_app.sim.motions import Playback, measures_legs, standing_legs
from sara_app.sim.simulator import Simulation


def _upper() -> Recording:
    t = np.arange(0, 1.0, 0.01)
    base = np.array([[0, 0, 1.65], [0, 0, 1.45], [0, 0, 1.0], [0, 0.18, 1.42],
                     [0, -0.18, 1.42], [0.1, 0.2, 1.15], [0.1, -0.2, 1.15], [0.3, 0.2, 1.1],
                     [0.3, -0.2, 1.1]])  # fmt: skip
    y = np.repeat(base[None], len(t), axis=0)
    y[:, :, 0] += 0.3 * t[:, None]  # stepping forward at 0.3 m/s
    return Recording("u", "upper", t, y, "test")


def test_an_upper_body_recording_stands_on_straight_legs_under_its_pelvis() -> None:
    rec = _upper()
    y = standing_legs(rec.positions_m)
    assert y.shape == (len(rec.times_s), len(FULL_JOINTS), 3)
    np.testing.assert_array_equal(y[:, : len(UPPER_JOINTS)], rec.positions_m)
    i = {j: k for k, j in enumerate(FULL_JOINTS)}
    pelvis = rec.positions_m[:, UPPER_JOINTS.index("pelvis")]
    for s, sign in (("l", 1.0), ("r", -1.0)):  # the person faces +x: left is +y
        hip, knee, ankle = y[:, i[f"{s}_hip"]], y[:, i[f"{s}_knee"]], y[:, i[f"{s}_ankle"]]
        assert np.all(sign * (hip[:, 1] - pelvis[:, 1]) > 0.05)
        for j in ("hip", "knee", "ankle"):  # the scripted people's standing legs, body frame
            np.testing.assert_allclose(y[:, i[f"{s}_{j}"]] - pelvis, np.broadcast_to(
                STANDING_LEGS_M[f"{s}_{j}"], pelvis.shape), atol=1e-12)  # fmt: skip
        assert np.all(ankle[:, 2] < knee[:, 2]) and np.all(knee[:, 2] < hip[:, 2])
    play = Playback(rec)
    assert not measures_legs(play) and play.pose(0.5, np.zeros((0, 2, 3)), np.zeros(0)).shape == (
        15,
        3,
    )


def test_the_simulated_sensor_of_an_upper_body_recording_does_not_measure_the_legs(
    tmp_path,
) -> None:
    from sara_app.human.recordings import save_csv

    path = tmp_path / "u.csv"
    save_csv(_upper(), path)
    data = load_scenario("cmu_walk").model_dump(mode="json")
    data["humans"] = [{"id": "u", "type": "recording", "recording": str(path)}]
    from sara_app.scenario import parse_scenario

    sim = Simulation(parse_scenario(data))
    for _ in range(60):
        sim.step()
    st = sim.sensors[0].track.state
    assert not sim.sensors[0].legs_measured and st.stamp_s is not None
    legs = [FULL_JOINTS.index(j) for j in FULL_JOINTS[len(UPPER_JOINTS) :]]
    assert np.isinf(st.dv[legs]).all() and np.isfinite(st.dv[: len(UPPER_JOINTS)]).all()
    assert st.widen_m is not None and st.widen_m.max() >= 1.2  # the unmeasured legs' reach


@pytest.mark.parametrize(
    ("kind", "tracks", "legs"),
    [("upper", "full", True), ("full", "upper", False), ("full", "auto", True)],
)
def test_the_sensor_measures_what_its_tracker_tracks(tmp_path, kind, tracks, legs) -> None:
    """A full-body tracker measures the standing legs an upper-body recording stands on (they
    are the simulated person's legs); an upper-body tracker leaves a full recording's legs
    unmeasured, widened."""
    from sara_app.human.recordings import save_csv
    from sara_app.scenario import parse_scenario

    path = tmp_path / "r.csv"
    save_csv(_upper() if kind == "upper" else load_recording("02_01"), path)
    data = load_scenario("cmu_walk").model_dump(mode="json")
    data["humans"] = [{"id": "p", "type": "recording", "recording": str(path),
                       "sensor": {"tracks": tracks}}]  # fmt: skip
    sim = Simulation(parse_scenario(data))
    for _ in range(60):
        sim.step()
    st = sim.sensors[0].track.state
    leg_joints = [FULL_JOINTS.index(j) for j in FULL_JOINTS[len(UPPER_JOINTS) :]]
    assert sim.sensors[0].legs_measured == legs
    assert np.isfinite(st.dv[leg_joints]).all() == legs
