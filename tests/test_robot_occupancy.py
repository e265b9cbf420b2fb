"""Robot occupancy over time intervals: soundness against dense sampling of the true motion,
tightness, the Lipschitz constants, and input errors.

The trajectories are generated here (piecewise cubic Hermite joint motions with random knot
velocities, or constant-speed single-joint motions) with ``qd_bound`` the exact maximum of
``|q_dot|`` of the true polynomial on each interval. The reference kinematics is pinocchio
(``RobotModel.link_capsules_batch``), independent of the module's vectorised forward kinematics,
and the containment test uses its own point-to-segment distance.
"""

from __future__ import annotations

import types

import numpy as np
import pinocchio as pin
import pytest

from sara_app.errors import InputError, ParameterError, RobotModelError
from sara_app.robot.model import RobotModel, load_robot
from sara_app.robot.occupancy import ROUNDING_SLACK_M, RobotOccupancy

ROBOTS = ("panda", "ur5e")
BOUNDS = ("lipschitz", "local")
POINTS_PER_INTERVAL = 50


@pytest.fixture(scope="module", params=ROBOTS)
def robot(request: pytest.FixtureRequest) -> tuple[RobotModel, RobotOccupancy]:
    model = load_robot(request.param)
    return model, RobotOccupancy(model)


# ---------------------------------------------------------------------------------------------
# Helpers: reference distances, trajectories, dense samples of the link capsules


def _dist_point_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Plain point-to-segment distance, broadcast (kept here, independent of geometry.py)."""
    d = b - a
    dd = np.sum(d * d, axis=-1)
    s = np.sum((p - a) * d, axis=-1) / np.where(dd > 0, dd, 1.0)
    s = np.clip(np.where(dd > 0, s, 0.0), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[..., None] * d), axis=-1)


def _hermite(q0, q1, v0, v1, dt, x):
    """Cubic Hermite position at normalised times ``x (m,)``: ``(m, n)``."""
    x = x[:, None]
    h00, h10 = 2 * x**3 - 3 * x**2 + 1, x**3 - 2 * x**2 + x
    h01, h11 = -2 * x**3 + 3 * x**2, x**3 - x**2
    return h00 * q0 + h10 * dt * v0 + h01 * q1 + h11 * dt * v1


def _hermite_speed_max(q0, q1, v0, v1, dt):
    """Exact ``max |q_dot|`` of the cubic Hermite on ``[0, dt]`` per joint: q_dot is the quadratic
    ``A x^2 + B x + C`` in ``x = t / dt``; its maximum modulus is at an end or at the vertex."""
    A = 6 * (q0 - q1) / dt + 3 * v0 + 3 * v1
    B = -6 * (q0 - q1) / dt - 4 * v0 - 2 * v1
    C = v0
    m = np.maximum(np.abs(C), np.abs(A + B + C))
    xs = -B / (2 * np.where(A != 0, A, 1.0))
    inside = (A != 0) & (xs > 0) & (xs < 1)
    return np.where(inside, np.maximum(m, np.abs((A * xs + B) * xs + C)), m)


def _random_trajectory(
    model: RobotModel,
    rng: np.random.Generator,
    K: int,
    dt_range: tuple[float, float],
    vscale: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Times, knots ``q``, knot velocities ``v`` and the exact per-interval speed maxima."""
    lim = model.limits
    n = model.n_dof
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(dt_range[0], dt_range[1], K))])
    dt = np.diff(t)
    v = rng.uniform(-1, 1, (K + 1, n)) * lim.v_max * vscale
    q = np.empty((K + 1, n))
    q[0] = rng.uniform(0.7 * lim.q_min + 0.3 * lim.q_max, 0.3 * lim.q_min + 0.7 * lim.q_max)
    for k in range(K):
        drift = rng.uniform(-1, 1, n) * lim.v_max * vscale * 0.5
        q[k + 1] = q[k] + dt[k] * (0.5 * (v[k] + v[k + 1]) + drift)
    qd_bound = _hermite_speed_max(q[:-1], q[1:], v[:-1], v[1:], dt[:, None])
    return t, q, v, qd_bound


def _capsule_points(E: np.ndarray, r: np.ndarray, rng: np.random.Generator, n_surface: int):
    """Points of the capsules ``E (S, L, 2, 3)``, radii ``(L,)``: the end centres, the two tips
    and ``n_surface`` points on the surface at random axis parameters and random directions
    normal to the axis (any direction for a ball). Returns ``(S, L, m, 3)``."""
    axis = E[:, :, 1] - E[:, :, 0]
    length = np.linalg.norm(axis, axis=-1, keepdims=True)
    u = np.where(length > 0, axis / np.where(length > 0, length, 1.0), 0.0)
    rr = r[None, :, None]
    pts = [E[:, :, 0], E[:, :, 1], E[:, :, 0] - u * rr, E[:, :, 1] + u * rr]
    for _ in range(n_surface):
        s = rng.uniform(0, 1, E.shape[:2] + (1,))
        w = rng.normal(size=E.shape[:2] + (3,))
        w -= np.sum(w * u, axis=-1, keepdims=True) * u
        w /= np.linalg.norm(w, axis=-1, keepdims=True)
        pts.append(E[:, :, 0] + s * axis + rr * w)
    out = np.stack(pts, axis=2)
    assert np.all(np.isfinite(out))
    return out


def _excess(model, ends_k, rad_k, qs, rng, n_surface=8):
    """For dense configurations ``qs (m, n)`` inside one interval: ``(distance of each sampled
    capsule point to the interval capsule axis - interval radius)`` ``(m, L, points)``."""
    E = model.link_capsules_batch(qs)
    P = _capsule_points(E, model.radius_m, rng, n_surface)
    a = ends_k[None, :, None, 0]
    b = ends_k[None, :, None, 1]
    return _dist_point_segment(P, a, b) - rad_k[None, :, None]


# ---------------------------------------------------------------------------------------------
# Kinematics and Lipschitz constants


def test_link_ends_match_pinocchio_with_base_pose() -> None:
    T = np.eye(4)
    c, s = np.cos(0.7), np.sin(0.7)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = [0.4, -1.2, 0.8]
    rng = np.random.default_rng(5)
    for name in ROBOTS:
        model = load_robot(name, T_world_base=T)
        occ = RobotOccupancy(model)
        Q = rng.uniform(model.limits.q_min, model.limits.q_max, (40, model.n_dof))
        np.testing.assert_allclose(occ.link_ends(Q), model.link_capsules_batch(Q), atol=1e-12)
        # a second, longer batch exercises the buffer growth
        Q = rng.uniform(model.limits.q_min, model.limits.q_max, (70, model.n_dof))
        np.testing.assert_allclose(occ.link_ends(Q), model.link_capsules_batch(Q), atol=1e-12)


def test_lipschitz_bounds_the_distance_to_every_moving_axis(robot) -> None:
    """Over random configurations, the capsule (end balls) never comes farther from joint j's
    axis than L[i, j]; L is zero exactly for joints that do not carry the link."""
    model, occ = robot
    pm = model.pin_model
    data = pm.createData()
    rng = np.random.default_rng(11)
    Q = rng.uniform(model.limits.q_min, model.limits.q_max, (300, model.n_dof))
    E = model.link_capsules_batch(Q)  # (S, L, 2, 3), base pose is identity here
    worst = np.zeros_like(occ.lipschitz)
    for s in range(Q.shape[0]):
        pin.forwardKinematics(pm, data, Q[s])
        for j in range(1, pm.njoints):
            M = data.oMi[j]
            axis = M.rotation[:, 2]  # both robots rotate about their joint frames' z axes
            rel = E[s] - M.translation
            perp = np.linalg.norm(rel - (rel @ axis)[..., None] * axis, axis=-1).max(axis=-1)
            worst[:, j - 1] = np.maximum(worst[:, j - 1], perp + model.radius_m)
    frame_joint = [
        pm.frames[pm.getFrameId(ln, pin.FrameType.BODY)].parentJoint for ln in model.link_names
    ]
    for i, m in enumerate(frame_joint):
        support = set(int(j) for j in pm.supports[m]) - {0}
        for j in range(1, pm.njoints):
            if j in support:
                assert worst[i, j - 1] <= occ.lipschitz[i, j - 1] + 1e-12, (i, j)
            else:
                assert occ.lipschitz[i, j - 1] == 0.0
    moving = occ.lipschitz > 0
    share = worst[moving] / occ.lipschitz[moving]
    print(
        f"\n{model.name}: largest sampled axis distance / L: min {share.min():.2f}, "
        f"median {np.median(share):.2f}, max {share.max():.3f}"
    )
    assert share.max() > 0.95  # the constant is reached (nearly) in some configuration


# ---------------------------------------------------------------------------------------------
# Soundness against dense sampling


@pytest.mark.parametrize("bound", BOUNDS)
def test_interval_capsules_contain_the_true_motion(robot, bound: str) -> None:
    model, occ = robot
    rng = np.random.default_rng(2024)
    x = np.linspace(0.0, 1.0, POINTS_PER_INTERVAL)
    used = []
    for _ in range(12):
        K = 6
        t, q, v, qd_bound = _random_trajectory(model, rng, K, (0.001, 0.03), 0.6)
        ends, radius = occ.intervals(q, qd_bound, t, bound=bound)
        assert ends.shape == (K, model.n_links, 2, 3) and radius.shape == (K, model.n_links)
        added = radius - model.radius_m - ROUNDING_SLACK_M
        for k in range(K):
            dt = t[k + 1] - t[k]
            qs = _hermite(q[k], q[k + 1], v[k], v[k + 1], dt, x)
            ex = _excess(model, ends[k], radius[k], qs, rng)
            assert ex.max() <= 0.0, f"interval {k}: a link point is {ex.max():.3g} m outside"
            # share of the added radius the true motion uses (1 = the bound is tight)
            grow = ex + added[k][None, :, None]
            moving = added[k] > 0
            used.append(np.max(grow[:, moving] / added[k][moving][None, :, None]))
    print(f"\n{model.name} {bound}: at most {max(used):.2f} of the added radius is used")


@pytest.mark.parametrize("bound", BOUNDS)
def test_single_joint_motion_is_nearly_tight_and_halving_the_bound_fails(robot, bound) -> None:
    """Constant-speed single-joint motions: contained with the true bound; with the bound halved
    the dense samples escape in some trials (the containment test can fail), and the true motion
    uses most of the added radius (the rest: a displacement along the capsule axis stays inside
    the mid-axis capsule, and the sampled surface directions miss the extreme one)."""
    model, occ = robot
    lim = model.limits
    rng = np.random.default_rng(7)
    x = np.linspace(0.0, 1.0, POINTS_PER_INTERVAL)
    K, dt = 3, 0.02
    t = np.arange(K + 1) * dt
    escaped, used = 0, []
    for trial in range(2 * model.n_dof):
        j = trial % model.n_dof
        q0 = rng.uniform(lim.q_min, lim.q_max)
        v = np.zeros(model.n_dof)
        v[j] = lim.v_max[j] * rng.choice([-1.0, 1.0])
        q = q0 + t[:, None] * v
        qd_true = np.tile(np.abs(v), (K, 1))
        ends, radius = occ.intervals(q, qd_true, t, bound=bound)
        ends_h, radius_h = occ.intervals(q, 0.5 * qd_true, t, bound=bound)
        added = radius - model.radius_m - ROUNDING_SLACK_M
        trial_escaped = False
        for k in range(K):
            qs = q[k] + (x * dt)[:, None] * v
            ex = _excess(model, ends[k], radius[k], qs, rng, n_surface=16)
            assert ex.max() <= 0.0
            moving = added[k] > 0
            used.append(np.max((ex + added[k][None, :, None])[:, moving] / added[k][moving, None]))
            trial_escaped |= bool(_excess(model, ends_h[k], radius_h[k], qs, rng, 16).max() > 0)
        escaped += trial_escaped
    print(
        f"\n{model.name} {bound}: halved bound escapes in {escaped} of {2 * model.n_dof} "
        f"trials; at most {max(used):.3f} of the added radius used"
    )
    assert escaped >= 1
    assert max(used) > 0.75


def test_quarter_bound_escapes_on_random_motions(robot) -> None:
    """Multi-joint random motions use less of the bound (the joints' contributions do not add up
    in one direction): a quarter of the true speed bound lets the samples escape."""
    model, occ = robot
    rng = np.random.default_rng(99)
    x = np.linspace(0.0, 1.0, POINTS_PER_INTERVAL)
    worst = -np.inf
    for _ in range(6):
        t, q, v, qd_bound = _random_trajectory(model, rng, 4, (0.01, 0.03), 0.6)
        ends, radius = occ.intervals(q, 0.25 * qd_bound, t)
        for k in range(4):
            qs = _hermite(q[k], q[k + 1], v[k], v[k + 1], t[k + 1] - t[k], x)
            worst = max(worst, _excess(model, ends[k], radius[k], qs, rng).max())
    assert worst > 0.0


# ---------------------------------------------------------------------------------------------
# How much the bound adds


def test_added_radius_is_small_for_a_1ms_interval() -> None:
    """Moderate speed (half the joint velocity limits), a 1 ms interval: the Lipschitz
    enlargement of every link is below 3 mm (Panda 2.6 mm, UR5e 2.7 mm at the last link)."""
    for name in ROBOTS:
        model = load_robot(name)
        occ = RobotOccupancy(model)
        qd = 0.5 * model.limits.v_max[None]
        add = occ.added_radius(qd, np.array([0.0, 0.001]))[0]
        print(f"\n{name}: added radius per link (mm), 1 ms at 0.5 v_max: {np.round(add * 1e3, 2)}")
        assert add.shape == (model.n_links,)
        assert add[0] == 0.0  # the base does not move
        assert add.max() < 3e-3
        assert add.max() > 1e-3  # and it is not zero: it follows the chain lengths
        # linear in the interval length and in the speed bound
        add2 = occ.added_radius(2 * qd, np.array([0.0, 0.002]))[0]
        np.testing.assert_allclose(add2, 4 * add, rtol=1e-12)


def test_returned_capsule_is_inside_the_conservative_shortcut(robot) -> None:
    """The shortcut (enclose the two sample capsules, then grow by P/2) has the same axis and a
    radius larger by h (half the larger end displacement): measured here at 1 ms."""
    from sara_app.geometry.shapes import capsule_enclosing_capsules

    model, occ = robot
    rng = np.random.default_rng(3)
    h_all, add_all, local_share = [], [], []
    r = model.radius_m
    for _ in range(20):
        t, q, v, qd_bound = _random_trajectory(model, rng, 10, (0.001, 0.001), 0.5)
        ends, radius = occ.intervals(q, qd_bound, t)
        _, radius_local = occ.intervals(q, qd_bound, t, bound="local")
        E = occ.link_ends(q)
        enc_ends, enc_radius = capsule_enclosing_capsules(E[:-1], r, E[1:], r)
        np.testing.assert_allclose(enc_ends, ends, atol=1e-15)
        P_half = occ.added_radius(qd_bound, t)
        shortcut = enc_radius + P_half + ROUNDING_SLACK_M
        assert np.all(radius <= shortcut + 1e-15)
        assert np.all(enc_radius <= radius)  # h <= P/2: the two samples are inside
        assert np.all(radius_local <= radius + 1e-15)
        h_all.append((enc_radius - r)[:, 1:])
        add_all.append(P_half[:, 1:])
        local_share.append(((radius_local - r) / (radius - r))[:, 1:])
    h, add, ls = (np.concatenate(a).ravel() for a in (h_all, add_all, local_share))
    print(
        f"\n{model.name}, 1 ms at up to ~0.5 v_max: P/2 mean {add.mean() * 1e3:.3f} mm "
        f"(max {add.max() * 1e3:.3f}); the shortcut adds h, mean {h.mean() * 1e3:.3f} mm "
        f"(max {h.max() * 1e3:.3f}); local / lipschitz enlargement mean {ls.mean():.2f}"
    )


def test_swept_contains_every_interval_capsule(robot) -> None:
    model, occ = robot
    rng = np.random.default_rng(8)
    t, q, v, qd_bound = _random_trajectory(model, rng, 30, (0.005, 0.02), 0.6)
    ends, radius = occ.intervals(q, qd_bound, t)
    s_ends, s_radius = occ.swept(q, qd_bound, t)
    assert s_ends.shape == (model.n_links, 2, 3) and s_radius.shape == (model.n_links,)
    # A capsule is the hull of its end balls: it lies in the (convex) swept capsule iff both
    # end balls do.
    d = _dist_point_segment(ends, s_ends[None, :, None, 0], s_ends[None, :, None, 1])
    assert np.all(d + radius[:, :, None] <= s_radius[None, :, None] + 1e-12)


def test_intervals_of_a_trajectory_object(robot) -> None:
    """Anything with ``times``, ``q`` and ``v_bound`` arrays (the shielded trajectory) works."""
    model, occ = robot
    rng = np.random.default_rng(4)
    t, q, v, qd_bound = _random_trajectory(model, rng, 5, (0.001, 0.01), 0.5)
    traj = types.SimpleNamespace(times=t, q=q, v=v, v_bound=qd_bound)
    a = occ.intervals_of(traj)
    b = occ.intervals(q, qd_bound, t)
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])


def test_compiled_intervals_equal_the_formula_on_pinocchio_ends(robot) -> None:
    """The compiled pass equals the module docstring's formula evaluated with pinocchio's
    capsule ends: mid axes ``(E_k + E_k+1) / 2`` and ``r + dt / 2 L @ qd_bound + slack``; views
    (non-contiguous inputs) give the same result."""
    model, occ = robot
    rng = np.random.default_rng(5)
    t, q, _, qd_bound = _random_trajectory(model, rng, 7, (0.001, 0.02), 0.8)
    E = model.link_capsules_batch(q)
    ends, radius = occ.intervals(q, qd_bound, t)
    np.testing.assert_allclose(ends, 0.5 * (E[:-1] + E[1:]), rtol=0, atol=1e-12)
    ref = 0.5 * np.diff(t)[:, None] * (qd_bound @ occ.lipschitz.T) + model.radius_m
    np.testing.assert_allclose(radius, ref + ROUNDING_SLACK_M, rtol=1e-14, atol=0)
    q_f, v_f = np.asfortranarray(q), np.asfortranarray(qd_bound)
    ends2, radius2 = occ.intervals(q_f, v_f, t)
    np.testing.assert_array_equal(ends2, ends)
    np.testing.assert_array_equal(radius2, radius)


# ---------------------------------------------------------------------------------------------
# Errors


def test_bad_inputs_raise_input_error() -> None:
    model = load_robot("panda")
    occ = RobotOccupancy(model)
    n = model.n_dof
    t = np.array([0.0, 0.001, 0.002])
    q = np.zeros((3, n))
    qd = np.ones((2, n))
    occ.intervals(q, qd, t)  # valid
    cases = [
        ((np.zeros((3, n - 1)), qd, t), r"q has shape \(3, 6\); expected \(S, 7\)"),
        ((np.zeros(n), qd, t), r"q has shape \(7,\)"),
        ((np.zeros((1, n)), np.ones((0, n)), t[:1]), "at least 2"),
        ((q, np.ones((3, n)), t), r"qd_bound has shape \(3, 7\); expected \(2, 7\)"),
        ((q, np.ones((2, n - 1)), t), r"qd_bound has shape \(2, 6\)"),
        ((q, qd, t[:2]), r"t has shape \(2,\); expected \(3,\)"),
        ((np.where(np.eye(3, n) > 0, np.nan, 0.0), qd, t), r"q\[0, 0\] = nan"),
        ((q, np.where(np.eye(2, n) > 0, np.inf, 1.0), t), r"qd_bound\[0, 0\] = inf"),
        ((q, -qd, t), r"qd_bound\[0, 0\] = -1.0; expected finite values >= 0"),
        ((q, qd, np.array([0.0, np.nan, 0.002])), r"t\[1\] = nan"),
        ((q, qd, np.array([0.0, 0.002, 0.001])), "not strictly increasing: t\\[1\\] = 0.002"),
        ((q, qd, np.array([0.0, 0.001, 0.001])), "not strictly increasing"),
    ]
    for args, message in cases:
        with pytest.raises(InputError, match=message):
            occ.intervals(*args)
    with pytest.raises(InputError, match="not strictly increasing"):
        occ.swept(q, qd, t[::-1])
    with pytest.raises(InputError, match="qd_bound"):
        occ.added_radius(qd[:1], t)
    with pytest.raises(InputError, match=r"t has shape \(1,\)"):
        occ.added_radius(qd[:0], t[:1])
    with pytest.raises(InputError, match="expected"):
        occ.link_ends(np.ones((2, n + 1)))
    with pytest.raises(ParameterError, match="valid choices: lipschitz, local"):
        occ.intervals(q, qd, t, bound="exact")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="v_bound"):
        occ.intervals_of(types.SimpleNamespace(times=t, q=q))


PRISMATIC_URDF = """<?xml version="1.0"?>
<robot name="slider">
  <link name="base"><collision><geometry><box size="0.2 0.2 0.2"/></geometry></collision></link>
  <link name="carriage">
    <inertial><mass value="1.0"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0"
      izz="0.01"/></inertial>
    <collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision>
  </link>
  <joint name="slide" type="prismatic">
    <parent link="base"/><child link="carriage"/><axis xyz="1 0 0"/>
    <limit lower="-0.5" upper="0.5" velocity="1.0" effort="10"/>
  </joint>
  <sara_limits><joint name="slide" acceleration="5" jerk="100"/></sara_limits>
</robot>
"""


def test_prismatic_joints_are_rejected(tmp_path) -> None:
    path = tmp_path / "slider.urdf"
    path.write_text(PRISMATIC_URDF)
    model = RobotModel(path)
    with pytest.raises(RobotModelError, match="revolute joints only"):
        RobotOccupancy(model)
