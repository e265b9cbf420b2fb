"""Any robot: the shipped UR10e (written from Universal Robots' published DH table) agrees with
that table's forward kinematics, and runs closed loops with zero collisions (SSM) and zero
harmful contacts (PFL), also against adversarial people; a URDF of your own is used by path
with its acceleration and jerk limits in the scenario; URDFs missing inertias, collision
geometry or limits get errors naming the link or joint and the missing element."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from sara_app.bus.session import free_port
from sara_app.errors import RobotModelError, ScenarioError
from sara_app.robot.model import load_robot, urdf_dir
from sara_app.scenario import check_against_robot, load_scenario, parse_scenario
from sara_app.sim.simulator import Simulation

# Universal Robots' DH table of the UR10e: a, d, alpha (standard convention)
A = (0.0, -0.6127, -0.57155, 0.0, 0.0, 0.0)
D = (0.1807, 0.0, 0.0, 0.17415, 0.11985, 0.11655)
ALPHA = (np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0)


def _dh(q: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    for th, a, d, al in zip(q, A, D, ALPHA, strict=True):
        ct, st, ca, sa = np.cos(th), np.sin(th), np.cos(al), np.sin(al)
        T = T @ np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                          [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]])  # fmt: skip
    return T


def test_ur10e_kinematics_match_the_published_dh_table() -> None:
    robot = load_robot("ur10e")
    rng = np.random.default_rng(5)
    for q in [np.zeros(6), *rng.uniform(-np.pi, np.pi, (20, 6))]:
        np.testing.assert_allclose(robot.frame_pose(q, "tool0"), _dh(q), atol=1e-9)
    masses = [float(i.mass) for i in robot.pin_model.inertias[1:]]
    np.testing.assert_allclose(masses, [7.369, 13.051, 3.989, 2.1, 1.98, 0.615])
    np.testing.assert_allclose(robot.limits.v_max, [2 * np.pi / 3] * 2 + [np.pi] * 4)


def _run(mode: str, humans: list[dict] | None = None, duration_s: float | None = None):
    data = load_scenario("ur10e_close_worker").model_dump(mode="json")
    data["shield"]["mode"] = mode
    if humans is not None:
        data["humans"] = humans
    return Simulation(parse_scenario(data, f"ur10e {mode}")).run(duration_s)


@pytest.mark.parametrize("mode", ["ssm", "pfl"])
def test_ur10e_closed_loops_are_safe_and_reach_the_goal(mode: str) -> None:
    m = _run(mode)
    assert m.collisions_moving == 0 and m.harmful_contacts == 0
    assert m.time_to_goal_s is not None
    adversary = [{"id": "adv", "type": "adversarial", "strategy": "limbs",
                  "position_m": [1.2, 0.3], "seed": 11}]  # fmt: skip
    m = _run(mode, adversary, 6.0)
    if mode == "ssm":
        assert m.collisions_moving == 0
    else:  # PFL allows contact below the thresholds: never a harmful one
        assert m.harmful_contacts == 0


def _own_urdf(tmp_path: Path, drop: str | None = None) -> Path:
    """The UR10e as a user's URDF file: without <sara_limits>, and without ``drop`` ('inertial'
    of the forearm, 'collision' of the forearm)."""
    text = (urdf_dir() / "ur10e.urdf").read_text()
    head, tail = text.rsplit("<sara_limits>", 1)  # the last one: the header mentions it
    text = head + tail.split("</sara_limits>")[1]
    if drop is not None:
        start = text.index('<link name="forearm_link">')
        end = text.index("</link>", start)
        body = text[start:end]
        while f"<{drop}>" in body:
            i = body.index(f"<{drop}>")
            body = body[:i] + body[body.index(f"</{drop}>", i) + len(drop) + 3 :]
        text = text[:start] + body + text[end:]
    path = tmp_path / "my_arm.urdf"
    path.write_text(text)
    return path


def test_a_urdf_of_your_own_with_limits_in_the_scenario(tmp_path: Path) -> None:
    path = _own_urdf(tmp_path)
    data = load_scenario("ur10e_close_worker").model_dump(mode="json")
    data["robot"] = {"name": str(path)}
    with pytest.raises(ScenarioError, match="'shoulder_pan_joint' has no acceleration/jerk"):
        check_against_robot(parse_scenario(data, "no limits"))
    joints = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint",
              "wrist_2_joint", "wrist_3_joint")  # fmt: skip
    data["robot"]["joint_limits"] = {j: {"acceleration_rad_s2": 4.0, "jerk_rad_s3": 80.0}
                                     for j in joints}  # fmt: skip
    sc = parse_scenario(data, "own urdf")
    check_against_robot(sc)
    m = Simulation(sc).run(3.0)
    assert m.collisions_moving == 0 and m.cycles > 0
    # PFL on it: every link pair may clamp unless the scenario declares which cannot
    pfl = {**data, "shield": {**data["shield"], "mode": "pfl"}}
    m = Simulation(parse_scenario(pfl, "own urdf, pfl")).run(3.0)
    assert m.harmful_contacts == 0
    pfl["shield"]["pfl"] = {"unclampable_pairs": [["base_link", "elbow"]]}
    with pytest.raises(ScenarioError, match="'elbow' is not a link of .*valid: base_link"):
        check_against_robot(parse_scenario(pfl, "bad pair"))
    bad = dict(data["robot"], joint_limits={"nope": {"acceleration_rad_s2": 1, "jerk_rad_s3": 1}})
    with pytest.raises(ScenarioError, match="'nope'.*valid choices: shoulder_pan_joint"):
        check_against_robot(parse_scenario({**data, "robot": bad}, "bad joint"))
    with pytest.raises(ScenarioError, match="unknown robot 'ur11'.*ur10e"):
        parse_scenario({**data, "robot": {"name": "ur11"}}, "bad name")


@pytest.mark.parametrize(("drop", "message"), [
    ("inertial", "link 'forearm_link' .* has no <inertial>"),
    ("collision", "link 'forearm_link' .* has <visual> but no <collision>"),
])  # fmt: skip
def test_a_malformed_urdf_names_the_link_and_the_missing_element(
    tmp_path: Path, drop: str, message: str
) -> None:
    path = _own_urdf(tmp_path, drop)
    limits = dict.fromkeys(load_robot("ur10e").joint_names, (4.0, 80.0))
    with pytest.raises(RobotModelError, match=message):
        load_robot(path, joint_limits=limits)


def test_the_dashboard_draws_a_robot_given_by_path(tmp_path: Path) -> None:
    from sara_app.dashboard.viewer import Dashboard

    path = tmp_path / "arm.urdf"
    shutil.copy(urdf_dir() / "ur10e.urdf", path)
    dash = Dashboard(robot=str(path))
    dash.start(port=free_port())
    try:
        assert dash.scene is not None and len(dash.scene.joint_names) == 6
    finally:
        dash.stop()
