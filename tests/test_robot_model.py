"""Robot model: URDFs, limits, kinematics against DH, capsule enclosure, dynamics, errors."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sara_app.errors import (
    InputError,
    ParameterError,
    RobotModelError,
    UnknownNameError,
)
from sara_app.geometry.shapes import point_segment_distance
from sara_app.robot.capsule_fit import fit_capsule
from sara_app.robot.model import RobotModel, load_robot, robot_names, urdf_dir

URDF_DIR = Path(__file__).resolve().parent.parent / "urdf"

# ---------------------------------------------------------------------------------------------
# Published parameters (independent of the URDF files)

PANDA_LIMITS = {
    "q_min": [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973],
    "q_max": [2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973],
    "v_max": [2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61],
    "a_max": [15, 7.5, 10, 12.5, 15, 20, 20],
    "j_max": [7500, 3750, 5000, 6250, 7500, 10000, 10000],
    "tau_max": [87, 87, 87, 87, 12, 12, 12],
}
UR5E_LIMITS = {
    "q_min": [-2 * np.pi] * 6,
    "q_max": [2 * np.pi] * 6,
    "v_max": [np.pi] * 6,
    "tau_max": [150, 150, 150, 28, 28, 28],
}
PANDA_MASSES = [4.970684, 0.646926, 3.228604, 3.587895, 1.225946, 1.666555, 0.735522 + 0.73]
UR5E_MASSES = [3.761, 8.058, 2.846, 1.37, 1.3, 0.365]


def _rotx(a: float) -> np.ndarray:
    T = np.eye(4)
    T[1:3, 1:3] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return T


def _rotz(a: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return T


def _trans(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = [x, y, z]
    return T


def panda_dh_flange(q: np.ndarray) -> np.ndarray:
    """Franka's published modified-DH chain (a, d, alpha), flange d = 0.107."""
    rows = [
        (0, 0.333, 0),
        (0, 0, -np.pi / 2),
        (0, 0.316, np.pi / 2),
        (0.0825, 0, np.pi / 2),
        (-0.0825, 0.384, -np.pi / 2),
        (0, 0, np.pi / 2),
        (0.088, 0, np.pi / 2),
    ]
    T = np.eye(4)
    for (a, d, alpha), qi in zip(rows, q, strict=True):
        T = T @ _rotx(alpha) @ _trans(a, 0, 0) @ _rotz(qi) @ _trans(0, 0, d)
    return T @ _trans(0, 0, 0.107)


def ur5e_dh_flange(q: np.ndarray) -> np.ndarray:
    """Universal Robots' published standard-DH chain for the UR5e."""
    d = [0.1625, 0, 0, 0.1333, 0.0997, 0.0996]
    a = [0, -0.425, -0.3922, 0, 0, 0]
    alpha = [np.pi / 2, 0, 0, np.pi / 2, -np.pi / 2, 0]
    T = np.eye(4)
    for i in range(6):
        T = T @ _rotz(q[i]) @ _trans(0, 0, d[i]) @ _trans(a[i], 0, 0) @ _rotx(alpha[i])
    return T


ROBOTS = {
    "panda": ("panda_link8", panda_dh_flange, 7),
    "ur5e": ("tool0", ur5e_dh_flange, 6),
}


@pytest.fixture(scope="module", params=list(ROBOTS))
def robot(request: pytest.FixtureRequest) -> RobotModel:
    return load_robot(request.param)


def _random_q(robot: RobotModel, rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(robot.limits.q_min, robot.limits.q_max)


def _random_pose(u: np.ndarray) -> np.ndarray:
    """A rigid transform from 7 numbers in [0, 1]: a quaternion direction and a translation."""
    quat = u[:4] * 2 - 1
    quat = quat / max(np.linalg.norm(quat), 1e-9)
    T = np.eye(4)
    T[:3, :3] = pin.Quaternion(quat[3], quat[0], quat[1], quat[2]).toRotationMatrix()
    T[:3, 3] = (u[4:7] * 2 - 1) * 3.0
    return T


# ---------------------------------------------------------------------------------------------
# Loading and limits


def test_both_robots_load_with_published_limits() -> None:
    panda, ur5e = load_robot("panda"), load_robot("ur5e")
    assert (panda.n_dof, ur5e.n_dof) == (7, 6)
    for rob, ref in ((panda, PANDA_LIMITS), (ur5e, UR5E_LIMITS)):
        lim = rob.limits
        for key, value in ref.items():
            np.testing.assert_allclose(getattr(lim, key), value, rtol=0, atol=1e-12, err_msg=key)
        assert np.all(lim.q_min < lim.q_max)
        for arr in (lim.v_max, lim.a_max, lim.j_max, lim.tau_max):
            assert arr is not None and np.all(arr > 0)
    # UR5e acceleration/jerk are our own conservative choices (not published): just sane.
    assert np.all(ur5e.limits.a_max <= 20) and np.all(ur5e.limits.j_max >= ur5e.limits.a_max)


def test_masses_are_the_published_ones() -> None:
    for name, masses in (("panda", PANDA_MASSES), ("ur5e", UR5E_MASSES)):
        model = load_robot(name).pin_model
        # pinocchio merges fixed links (the Panda hand) into their parent joint's body.
        got = [model.inertias[j].mass for j in range(1, model.njoints)]
        np.testing.assert_allclose(got, masses, rtol=0, atol=1e-9)


@pytest.mark.parametrize("name", list(ROBOTS))
def test_urdfs_load_in_pinocchio_and_yourdfpy(name: str) -> None:
    import yourdfpy

    flange, dh, n = ROBOTS[name]
    path = URDF_DIR / f"{name}.urdf"
    model = pin.buildModelFromUrdf(str(path))
    assert model.nq == model.nv == n
    urdf = yourdfpy.URDF.load(str(path), load_meshes=False, build_collision_scene_graph=False)
    assert len(urdf.actuated_joint_names) == n
    urdf.update_cfg(np.zeros(n))
    np.testing.assert_allclose(urdf.get_transform(flange), dh(np.zeros(n)), atol=1e-9)


# ---------------------------------------------------------------------------------------------
# Kinematics


def test_home_flange_matches_dh_within_1mm(robot: RobotModel) -> None:
    flange, dh, n = ROBOTS[robot.name]
    T = robot.frame_pose(np.zeros(n), flange)
    ref = dh(np.zeros(n))
    assert np.linalg.norm(T[:3, 3] - ref[:3, 3]) < 1e-3
    np.testing.assert_allclose(T, ref, atol=1e-12)
    expected_home = {"panda": [0.088, 0.0, 0.926], "ur5e": [-0.8172, -0.2329, 0.0628]}
    np.testing.assert_allclose(T[:3, 3], expected_home[robot.name], atol=1e-12)


def test_fk_matches_dh_at_random_configurations(robot: RobotModel) -> None:
    flange, dh, _ = ROBOTS[robot.name]
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = _random_q(robot, rng)
        np.testing.assert_allclose(robot.frame_pose(q, flange), dh(q), atol=1e-12)


def test_link_capsules_match_batch_and_out_buffer(robot: RobotModel) -> None:
    rng = np.random.default_rng(2)
    qs = np.stack([_random_q(robot, rng) for _ in range(8)])
    batch = robot.link_capsules_batch(qs)
    assert batch.shape == (8, len(robot.link_names), 2, 3)
    out = np.empty((len(robot.link_names), 2, 3))
    for s, q in enumerate(qs):
        ends, radius = robot.link_capsules(q)
        np.testing.assert_allclose(ends, batch[s], atol=1e-14)
        filled, _ = robot.link_capsules(q, out_ends=out)
        assert filled is out
        np.testing.assert_array_equal(out, ends)
        assert radius is robot.radius_m
    with pytest.raises(InputError, match="out_ends"):
        robot.link_capsules(qs[0], out_ends=np.empty((1, 2, 3)))


def test_base_pose_and_margin() -> None:
    T = _random_pose(np.array([0.1, 0.7, 0.3, 0.9, 0.2, 0.5, 0.8]))
    plain = load_robot("panda")
    moved = load_robot("panda", T_world_base=T, margin_m=0.05)
    np.testing.assert_allclose(moved.radius_m, plain.radius_m + 0.05, atol=1e-15)
    q = _random_q(plain, np.random.default_rng(3))
    ends, _ = plain.link_capsules(q)
    ends_moved, _ = moved.link_capsules(q)
    np.testing.assert_allclose(ends_moved, ends @ T[:3, :3].T + T[:3, 3], atol=1e-12)
    np.testing.assert_allclose(
        moved.frame_pose(q, "panda_hand_tcp"), T @ plain.frame_pose(q, "panda_hand_tcp"), atol=1e-12
    )
    assert not moved.radius_m.flags.writeable and not moved.capsules_local.flags.writeable


def test_capsule_end_velocities_match_finite_differences(robot: RobotModel) -> None:
    rng = np.random.default_rng(4)
    T = _random_pose(rng.random(7))
    rob = RobotModel(robot.urdf_path, T_world_base=T)
    for _ in range(5):
        q, dq = _random_q(rob, rng), rng.normal(size=rob.n_dof)
        h = 1e-6
        fd = (rob.link_capsules(q + h * dq)[0] - rob.link_capsules(q - h * dq)[0]) / (2 * h)
        v = rob.capsule_end_velocities(q, dq)
        assert v.shape == (len(rob.link_names), 2, 3)
        np.testing.assert_allclose(v, fd, atol=1e-8)
        J = rob.link_jacobians(q)
        poses = rob.link_poses(q)
        fd_origin = (
            rob.link_poses(q + h * dq)[:, :3, 3] - rob.link_poses(q - h * dq)[:, :3, 3]
        ) / (2 * h)
        np.testing.assert_allclose(J[:, :3] @ dq, fd_origin, atol=1e-8)
        assert poses.shape == (len(rob.link_names), 4, 4)


# ---------------------------------------------------------------------------------------------
# Capsule enclosure of the true collision primitives


def _surface_samples(geometry: object, rng: np.random.Generator, n: int = 400) -> np.ndarray:
    """Points on the true surface of a coal primitive (in its own frame), corners included."""
    import coal

    if isinstance(geometry, coal.Box):
        h = np.asarray(geometry.halfSide)
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
        pts = rng.uniform(-1, 1, (n, 3))
        axis = rng.integers(0, 3, n)
        pts[np.arange(n), axis] = rng.choice([-1.0, 1.0], n)
        return np.concatenate([signs * h, pts * h])
    if isinstance(geometry, coal.Cylinder):
        r, hl = geometry.radius, geometry.halfLength
        phi = rng.uniform(0, 2 * np.pi, n)
        z = np.concatenate([np.full(n // 2, -hl), np.full(n - n // 2, hl)])
        z[::3] = rng.uniform(-hl, hl, len(z[::3]))  # side wall
        rim = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
        # the rims at the worst angles for any chord-based fit: dense exact circle points
        psi = np.linspace(0, 2 * np.pi, 1024, endpoint=False)
        rims = [
            np.stack([r * np.cos(psi), r * np.sin(psi), np.full(psi.size, s)], 1) for s in (-hl, hl)
        ]
        return np.concatenate([rim, *rims])
    if isinstance(geometry, coal.Sphere):
        d = rng.normal(size=(n, 3))
        return geometry.radius * d / np.linalg.norm(d, axis=1, keepdims=True)
    raise AssertionError(f"unexpected primitive {type(geometry).__name__}")


_GEOMS: dict[str, tuple[pin.GeometryModel, list[np.ndarray]]] = {}


def _geometry(robot: RobotModel) -> tuple[pin.GeometryModel, list[np.ndarray]]:
    if robot.name not in _GEOMS:
        gm = pin.buildGeomFromUrdf(
            robot.pin_model, str(robot.urdf_path), pin.GeometryType.COLLISION
        )
        rng = np.random.default_rng(5)
        samples = [_surface_samples(g.geometry, rng) for g in gm.geometryObjects]
        _GEOMS[robot.name] = (gm, samples)
    return _GEOMS[robot.name]


@settings(max_examples=30, deadline=None)
@given(
    name=st.sampled_from(list(ROBOTS)),
    u_q=st.lists(st.floats(0.0, 1.0), min_size=7, max_size=7),
    u_base=st.lists(st.floats(0.0, 1.0), min_size=7, max_size=7),
)
def test_capsules_enclose_every_collision_primitive(
    name: str, u_q: list[float], u_base: list[float]
) -> None:
    T = _random_pose(np.array(u_base))
    rob = load_robot(name, T_world_base=T)
    q = rob.limits.q_min + np.array(u_q[: rob.n_dof]) * (rob.limits.q_max - rob.limits.q_min)
    gm, samples = _geometry(rob)
    gd = pin.GeometryData(gm)
    data = rob.pin_model.createData()
    pin.updateGeometryPlacements(rob.pin_model, data, gm, gd, q)
    ends, radius = rob.link_capsules(q)
    covered = set()
    for i, g in enumerate(gm.geometryObjects):
        link = rob.pin_model.frames[g.parentFrame].name
        k = rob.link_names.index(link)
        covered.add(link)
        world = T @ gd.oMg[i].homogeneous
        pts = samples[i] @ world[:3, :3].T + world[:3, 3]
        dist = point_segment_distance(pts, ends[k])
        assert dist.max() <= radius[k] + 1e-12, (link, dist.max() - radius[k])
    assert covered == set(rob.link_names)


def test_fit_capsule_simple_shapes() -> None:
    # A sphere (centre + slack r) gives a ball of radius r.
    ends, r = fit_capsule(np.array([[0.1, -0.2, 0.3]]), 0.07)
    assert np.linalg.norm(ends[1] - ends[0]) < 1e-6 and abs(r - 0.07) < 1e-6
    # A box: all corners inside, volume no worse than the box's circumscribed ball.
    half = np.array([0.3, 0.05, 0.04])
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half
    ends, r = fit_capsule(corners)
    assert point_segment_distance(corners, ends).max() <= r
    assert r < np.linalg.norm(half[1:]) * 1.05  # the axis found is the long one
    length = np.linalg.norm(ends[1] - ends[0])
    assert np.pi * r**2 * length + 4 / 3 * np.pi * r**3 < 4 / 3 * np.pi * np.linalg.norm(half) ** 3


# ---------------------------------------------------------------------------------------------
# Dynamics


def test_mass_matrix_spd_and_kinetic_energy(robot: RobotModel) -> None:
    model = robot.pin_model
    data = model.createData()
    rng = np.random.default_rng(6)
    for _ in range(10):
        q, dq = _random_q(robot, rng), rng.normal(size=robot.n_dof)
        M = robot.mass_matrix(q)
        assert M.shape == (robot.n_dof, robot.n_dof)
        np.testing.assert_array_equal(M, M.T)
        assert np.linalg.eigvalsh(M).min() > 0
        pin.forwardKinematics(model, data, q, dq)
        ke = 0.0
        for j in range(1, model.njoints):
            v = pin.getVelocity(model, data, j, pin.ReferenceFrame.LOCAL)
            inertia = model.inertias[j]
            w = np.asarray(v.angular)
            v_com = np.asarray(v.linear) + np.cross(w, np.asarray(inertia.lever))
            ke += 0.5 * inertia.mass * v_com @ v_com + 0.5 * w @ np.asarray(inertia.inertia) @ w
        assert abs(0.5 * dq @ M @ dq - ke) <= 1e-9 * abs(ke)
        # M is the map from accelerations to torques at zero velocity, without gravity.
        ddq = rng.normal(size=robot.n_dof)
        tau = pin.rnea(model, data, q, np.zeros(robot.n_dof), ddq) - pin.rnea(
            model, data, q, np.zeros(robot.n_dof), np.zeros(robot.n_dof)
        )
        np.testing.assert_allclose(M @ ddq, tau, rtol=1e-9, atol=1e-12)


# ---------------------------------------------------------------------------------------------
# Errors


def test_unknown_robot_name_lists_choices() -> None:
    with pytest.raises(UnknownNameError) as info:
        load_robot("kuka_iiwa")
    message = str(info.value)
    assert "kuka_iiwa" in message and "panda" in message and "ur5e" in message
    assert isinstance(info.value, KeyError)
    assert {"panda", "ur5e"} <= set(robot_names())


def _panda_variant(tmp_path: Path, edit: str, replacement: str) -> Path:
    text = (URDF_DIR / "panda.urdf").read_text()
    assert edit in text
    path = tmp_path / "panda_variant.urdf"
    path.write_text(text.replace(edit, replacement))
    return path


def test_missing_sara_limit_names_the_joint(tmp_path: Path) -> None:
    line = '<joint name="panda_joint3" acceleration="10.0" jerk="5000.0"/>'
    path = _panda_variant(tmp_path, line, "")
    with pytest.raises(RobotModelError, match="panda_joint3"):
        load_robot(str(path))


def test_bad_sara_limits_are_reported(tmp_path: Path) -> None:
    line = '<joint name="panda_joint3" acceleration="10.0" jerk="5000.0"/>'
    unknown = _panda_variant(
        tmp_path, line, line + '<joint name="elbow" acceleration="1" jerk="1"/>'
    )
    with pytest.raises(RobotModelError, match=r"'elbow'.*valid choices: panda_joint1"):
        load_robot(str(unknown))
    negative = _panda_variant(tmp_path, line, line.replace('"10.0"', '"-1"'))
    with pytest.raises(RobotModelError, match=re.escape("'panda_joint3'")):
        load_robot(str(negative))


def test_bad_arguments() -> None:
    rob = load_robot("ur5e")
    with pytest.raises(InputError, match=r"\(6,\)"):
        rob.link_capsules(np.zeros(7))
    with pytest.raises(InputError):
        rob.link_capsules(np.full(6, np.nan))
    with pytest.raises(InputError):
        rob.link_capsules_batch(np.zeros((3, 5)))
    with pytest.raises(InputError, match="rigid"):
        load_robot("ur5e", T_world_base=np.diag([2.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ParameterError, match="margin_m"):
        load_robot("ur5e", margin_m=-0.01)
    with pytest.raises(UnknownNameError, match="tool0"):
        rob.frame_pose(np.zeros(6), "flange_typo")
    with pytest.raises(RobotModelError, match="not found"):
        load_robot("/nonexistent/robot.urdf")


_ONE_JOINT_URDF = """<?xml version="1.0"?>
<robot name="{name}">
  <link name="base"/>
  <joint name="j1" type="revolute">
    <parent link="base"/><child link="arm"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1" velocity="1" effort="10"/>
  </joint>
  <link name="arm">
    <inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/>
    </inertial>
    <collision><origin xyz="0.2 0 0" rpy="0 0.3 0"/>
      <geometry><mesh filename="bar.stl" scale="1 1 2"/></geometry></collision>
  </link>
  <sara_limits><joint name="j1" acceleration="2" jerk="20"/></sara_limits>
</robot>
"""


def test_mesh_geometry_and_urdf_dir_env(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import trimesh

    bar = trimesh.creation.box(extents=[0.4, 0.05, 0.03])
    bar.export(str(tmp_path / "bar.stl"))
    (tmp_path / "onejoint.urdf").write_text(_ONE_JOINT_URDF.format(name="onejoint"))
    monkeypatch.setenv("SARA_URDF_DIR", str(tmp_path))
    assert urdf_dir() == tmp_path and "onejoint" in robot_names()
    rob = load_robot("onejoint")
    assert rob.link_names == ("arm",) and rob.n_dof == 1
    q = np.array([0.4])
    ends, radius = rob.link_capsules(q)
    T = rob.link_poses(q)[0]
    vertices = np.asarray(bar.vertices) * [1, 1, 2]
    local = vertices @ _rotation_y(0.3).T + [0.2, 0, 0]
    world = local @ T[:3, :3].T + T[:3, 3]
    assert point_segment_distance(world, ends[0]).max() <= radius[0]
    assert radius[0] < 0.06  # a 0.05 x 0.06 cross-section, not a ball around the bar


def _rotation_y(a: float) -> np.ndarray:
    return np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
