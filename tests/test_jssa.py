"""JSSA: kinematics and index against finite differences, exact projection (KKT), fallbacks,
randomised closed-loop episodes with constant-velocity humans."""

from __future__ import annotations

import numpy as np
import pytest
from jssa_reference import project_halfspace_box

from sara_app.errors import ParameterError
from sara_app.robot.model import load_robot
from sara_app.safety.jssa import JssaController, JssaParams, integrate, make_params
from sara_app.safety.jssa_index import index_gradient, index_terms, safety_index
from sara_app.safety.jssa_kinematics import PointKinematics
from sara_app.safety.jssa_qp import project_polytope_box
from sara_app.studies.jssa_study import PANDA_HOME, panda_on_table, rigid_human


@pytest.fixture(scope="module")
def robot():
    return panda_on_table()


def test_point_kinematics_match_finite_differences() -> None:
    T = np.eye(4)
    c, s = np.cos(0.7), np.sin(0.7)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = [0.3, -0.2, 0.1]
    r = load_robot("panda", T_world_base=T)
    kin = PointKinematics(r)
    rng = np.random.default_rng(1)
    for trial in range(3):
        q0 = PANDA_HOME + rng.normal(0, 0.3, 7)
        v0, a0, u = rng.normal(0, 0.5, 7), rng.normal(0, 2, 7), rng.normal(0, 30, 7)

        def state(t, q0=q0, v0=v0, a0=a0, u=u):
            return q0 + v0 * t + a0 * t * t / 2 + u * t**3 / 6, v0 + a0 * t + u * t * t / 2

        link, frac = 3 + 2 * trial, rng.random()

        def point(t, link=link, frac=frac, state=state):
            e, _ = r.link_capsules(state(t)[0])
            return e[link, 0] + frac * (e[link, 1] - e[link, 0])

        kin.update(q0, v0, a0)
        v, a, c_, J = kin.points(np.array([link]), point(0.0)[None])
        h = 1e-3
        P = np.array([point(k * h) for k in (-2, -1, 0, 1, 2)])
        v_fd = (P[3] - P[1]) / (2 * h)
        a_fd = (P[3] - 2 * P[2] + P[1]) / h**2
        j_fd = (P[4] - 2 * P[3] + 2 * P[1] - P[0]) / (2 * h**3)
        np.testing.assert_allclose(v[0], v_fd, atol=1e-5)
        np.testing.assert_allclose(J[0] @ v0, v[0], atol=1e-12)
        np.testing.assert_allclose(a[0], a_fd, atol=1e-4)
        np.testing.assert_allclose(J[0] @ u + c_[0], j_fd, atol=1e-3 * (1 + np.abs(j_fd).max()))


def test_index_gradient_matches_finite_differences() -> None:
    rng = np.random.default_rng(2)
    dp, dv, da = rng.normal(size=(3, 5, 3))
    r_sum = np.full(5, 0.2)
    lam1, lam2 = 3.0, 1.5

    def phi(dp, dv, da):
        return safety_index(*index_terms(dp, dv, da, r_sum), 0.05, lam1, lam2)

    _, gp, gv, ga = index_gradient(dp, dv, da, r_sum, lam1, lam2)
    eps = 1e-6
    for k, (grad, which) in enumerate(((gp, 0), (gv, 1), (ga, 2))):
        for i in range(3):
            args_p = [dp.copy(), dv.copy(), da.copy()]
            args_m = [dp.copy(), dv.copy(), da.copy()]
            args_p[which][:, i] += eps
            args_m[which][:, i] -= eps
            fd = (phi(*args_p) - phi(*args_m)) / (2 * eps)
            np.testing.assert_allclose(grad[:, i], fd, rtol=1e-5, atol=1e-6, err_msg=str(k))


def test_exact_projection_satisfies_kkt_and_matches_qp_solver() -> None:
    rng = np.random.default_rng(3)
    n = 7
    for _ in range(60):
        u0 = rng.normal(0, 2, n)
        w = rng.uniform(0.5, 2.0, n)
        g = rng.normal(size=n) * (rng.random(n) > 0.2)
        lo, hi = -rng.uniform(0.5, 2, n), rng.uniform(0.5, 2, n)
        b = float(rng.normal(0, 2))
        u, mu, ok = project_halfspace_box(u0, w, g, b, lo, hi)
        u_min = np.where(g > 0, lo, hi)
        assert ok == (g @ u_min <= b + 1e-9)
        if not ok:
            continue
        # primal feasibility, dual feasibility, complementary slackness
        assert g @ u <= b + 1e-9 and np.all(u >= lo - 1e-12) and np.all(u <= hi + 1e-12)
        assert mu >= 0 and abs(mu * (g @ u - b)) < 1e-7
        # stationarity: r = -(w (u - u0) + mu g) is the box multiplier: >= 0 at hi, <= 0 at lo,
        # 0 inside
        r = -(w * (u - u0) + mu * g)
        at_hi, at_lo = np.isclose(u, hi), np.isclose(u, lo)
        inside = ~(at_hi | at_lo)
        assert np.all(np.abs(r[inside]) < 1e-8)
        assert np.all(r[at_hi] >= -1e-8) and np.all(r[at_lo] <= 1e-8)
        u_qp, ok_qp = project_polytope_box(u0, w, g[None], np.array([b]), lo, hi)
        assert ok_qp
        np.testing.assert_allclose(u, u_qp, atol=1e-6)


def test_params_validation() -> None:
    with pytest.raises(ParameterError, match="complex roots"):
        make_params(lambda_1=1.0, lambda_2=1.0)
    with pytest.raises(ParameterError):
        make_params(d_min_m=-0.1)
    with pytest.raises(ParameterError, match="weights"):
        JssaController(load_robot("panda"), JssaParams(weights=(1.0, 2.0)))


def test_bad_inputs_give_fallback_brake_never_an_exception(robot) -> None:
    ctrl = JssaController(robot, JssaParams())
    h = rigid_human(np.array([1.2, 0.0]), np.pi, np.array([-1.0, 0.0]), np.zeros(2))
    qd, qdd = np.full(7, 0.3), np.full(7, 1.0)
    u0 = np.zeros(7)
    bad_ends = h.ends.copy()
    bad_ends[3, 0, 1] = np.nan
    cases = [
        (PANDA_HOME, qd, qdd, u0, None, h.radius, h.vel, 0.008),
        (PANDA_HOME, qd, qdd, u0, bad_ends, h.radius, h.vel, 0.008),
        (PANDA_HOME, qd, qdd, u0, h.ends, h.radius[:3], h.vel, 0.008),
        (PANDA_HOME, qd, qdd, u0, h.ends, h.radius, None, 0.008),
        (PANDA_HOME * np.nan, qd, qdd, u0, h.ends, h.radius, h.vel, 0.008),
        (PANDA_HOME, qd, qdd, np.full(7, np.inf), h.ends, h.radius, h.vel, 0.008),
        (PANDA_HOME, qd, qdd, u0, h.ends, h.radius, h.vel, float("nan")),
        (PANDA_HOME, "junk", None, u0, "junk", h.radius, h.vel, 0.008),
    ]
    for args in cases:
        res = ctrl.step(*args)
        assert res.fallback and res.active
        assert np.all(np.isfinite(res.jerk)) and np.all(np.abs(res.jerk) <= ctrl.jerk_hi)
    assert ctrl.stats["fallback"] == len(cases) == ctrl.stats["invalid_input"]
    # the brake opposes the motion
    res = ctrl.step(PANDA_HOME, qd, np.zeros(7), u0, None, None, None, 0.008)
    assert np.all(res.jerk < 0)
    # no humans at all is not an error
    none3 = np.zeros((0, 2, 3))
    empty = ctrl.step(PANDA_HOME, qd, qdd, u0, none3, np.zeros(0), none3, 0.008)
    assert not empty.fallback and not empty.active


def _lateral_walker(x_line: float, y0: float, speed: float):
    """Constant-velocity human facing the robot (-x), walking along y at x = x_line."""
    v = np.array([0.0, -np.sign(y0) * speed])

    def fn(t: float):
        return rigid_human(np.array([x_line, y0]) + t * v, np.pi, v, np.zeros(2))

    return fn


@pytest.mark.parametrize("mode", ["single", "multi"])
def test_random_constant_velocity_episodes_keep_d_min_and_jerk_bounds(robot, mode) -> None:
    from sara_app.studies.jssa_study import Scenario, run_episode

    rng = np.random.default_rng(4 if mode == "single" else 5)
    params = JssaParams(lambda_1=3.0, lambda_2=1.0, mode=mode)
    for _ in range(2):
        walker = _lateral_walker(
            rng.uniform(1.05, 1.3), rng.choice([-1.0, 1.0]) * rng.uniform(1.5, 2.0),
            rng.uniform(0.5, 1.2),
        )  # fmt: skip
        sc = Scenario(robot, PANDA_HOME.copy(), walker, duration_s=3.0)
        ctrl = JssaController(robot, params)
        tr = run_episode(sc, ctrl)
        assert tr.active.any()  # the human did come close enough to matter
        assert tr.distance_m.min() > params.d_min_m
        assert np.all(np.abs(tr.jerk) <= robot.limits.j_max * (1 + 1e-12))


def test_integrate_is_eq1() -> None:
    q, qd, qdd, u = np.ones(2), np.array([0.5, -1.0]), np.array([2.0, 0.0]), np.array([-6.0, 3.0])
    q1, qd1, qdd1 = integrate(q, qd, qdd, u, 0.1)
    np.testing.assert_allclose(qdd1, qdd + 0.1 * u)
    np.testing.assert_allclose(qd1, qd + 0.1 * qdd + 0.005 * u)
    np.testing.assert_allclose(q1, q + 0.1 * qd + 0.005 * qdd + 0.001 / 6 * u)


def _rot(w: np.ndarray, t: float) -> np.ndarray:
    """Rotation by the angle vector ``w t`` (Rodrigues)."""
    th = np.linalg.norm(w) * t
    k = w / np.linalg.norm(w)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def test_sliding_correction_gives_the_second_derivative_of_the_capsule_distance() -> None:
    """A rigid link (translating with acceleration, rotating) against a limb whose ends move at
    constant but different velocities: d'' with the sliding correction matches finite
    differences of the true segment distance; the material-point d'' of eq. 12 does not."""
    from jssa_reference import sliding_correction

    from sara_app.geometry.shapes import segment_segment_closest

    rng = np.random.default_rng(7)
    errors_material, checked = [], 0
    while checked < 12:
        c0, vc, ac = rng.normal(0, 0.3, 3), rng.normal(0, 0.5, 3), rng.normal(0, 1.0, 3)
        r_loc = rng.normal(0, 0.2, (2, 3))
        w = rng.normal(0, 1.0, 3)
        B0 = rng.normal(0, 0.3, (2, 3)) + np.array([0.0, 0.0, 0.4])
        vb = rng.normal(0, 0.5, (2, 3))

        def ends(t, c0=c0, vc=vc, ac=ac, r_loc=r_loc, w=w, B0=B0, vb=vb):
            c = c0 + vc * t + 0.5 * ac * t * t
            return c + r_loc @ _rot(w, t).T, B0 + vb * t, c

        A, B, c = ends(0.0)
        dist, s, t = segment_segment_closest(A[None], B[None])
        s, t = float(s[0]), float(t[0])
        if not (0.05 < s < 0.95 or 0.05 < t < 0.95) or dist[0] < 0.05:
            continue
        checked += 1
        p_r, p_o = A[0] + s * (A[1] - A[0]), B[0] + t * (B[1] - B[0])
        v_r = vc + np.cross(w, p_r - c)
        a_r = ac + np.cross(w, np.cross(w, p_r - c))
        v_o = vb[0] + t * (vb[1] - vb[0])
        axis_r = A[1] - A[0]
        slide = sliding_correction(
            (p_r - p_o)[None], (v_r - v_o)[None], axis_r[None], np.cross(w, axis_r)[None],
            (B[1] - B[0])[None], (vb[1] - vb[0])[None], np.array([s]), np.array([t]),
        )  # fmt: skip
        r_sum = np.zeros(1)
        args = ((p_r - p_o)[None], (v_r - v_o)[None], a_r[None], r_sum)
        _, d1, d2 = index_terms(*args, slide)
        _, _, d2_material = index_terms(*args)
        h = 1e-4
        D = [segment_segment_closest(*(x[None] for x in ends(k * h)[:2]))[0][0] for k in (-1, 0, 1)]
        fd1, fd2 = (D[2] - D[0]) / (2 * h), (D[2] - 2 * D[1] + D[0]) / h**2
        np.testing.assert_allclose(d1[0], fd1, atol=1e-6)
        np.testing.assert_allclose(d2[0], fd2, atol=1e-3 * (1 + abs(fd2)))
        errors_material.append(abs(d2_material[0] - fd2))
        assert slide[0] >= 0.0
    assert max(errors_material) > 0.1  # eq. 12 alone misses the sliding


def test_compiled_constraint_terms_equal_the_index_functions() -> None:
    from jssa_reference import linear_constraints

    from sara_app.safety import jssa_kernels
    from sara_app.safety.jssa_kernels import constraint_terms

    rng = np.random.default_rng(3)
    K, n = 5, 7
    p_r, v_r, a_r, c_r, p_o, v_o = rng.normal(0, 0.5, (6, K, 3))
    J_r = rng.normal(0, 0.3, (K, 3, n))
    r_sum, slide = rng.uniform(0.05, 0.2, K), rng.uniform(0.0, 0.3, K)
    args = (0.004, 0.05, 3.0, 1.0)
    out = [np.empty(K) for _ in range(5)] + [np.empty((K, n))]
    constraint_terms(p_r, v_r, a_r, c_r, J_r, p_o, v_o, r_sum, slide, *args, *out)
    d, d1, d2 = index_terms(p_r - p_o, v_r - v_o, a_r, r_sum, slide)
    phi0, g = linear_constraints(p_r, v_r, a_r, c_r, J_r, p_o, v_o, r_sum, *args, slide)
    expect = (d, d1, d2, safety_index(d, d1, d2, 0.05, 3.0, 1.0), phi0, g)
    for got, want in zip(out, expect):
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    # the sliding correction, with interior, boundary and parallel closest points
    from jssa_reference import sliding_correction

    axis_r, omega, axis_o, axis_o_dot = rng.normal(0, 0.3, (4, K, 3))
    axis_o[0] = 2.0 * axis_r[0]  # parallel
    s, t = np.array([0.5, 0.0, 0.3, 1.0, 0.7]), np.array([0.4, 0.6, 1.0, 0.0, 0.2])
    slide_c = np.empty(K)
    jssa_kernels.sliding_terms(
        p_r - p_o, v_r - v_o, axis_r, omega, axis_o, axis_o_dot, s, t, slide_c
    )  # fmt: skip
    want = sliding_correction(
        p_r - p_o, v_r - v_o, axis_r, np.cross(omega, axis_r), axis_o, axis_o_dot, s, t
    )  # fmt: skip
    np.testing.assert_allclose(slide_c, want, rtol=1e-12, atol=1e-15)
    assert slide_c[3] == 0.0 and np.all(slide_c[[0, 1, 2, 4]] > 0)


def test_compiled_projection_equals_the_exact_one() -> None:
    from sara_app.safety import jssa_kernels
    from sara_app.safety.jssa_qp import FEAS_TOL

    rng = np.random.default_rng(11)
    n_infeasible = 0
    for _ in range(300):
        n = 7
        u0, g = rng.normal(0, 100, n), rng.normal(0, 1, n)
        g[rng.random(n) < 0.2] = 0.0
        w = rng.uniform(0.5, 2.0, n)
        hi = rng.uniform(10, 200, n)
        lo = -rng.uniform(10, 200, n)
        b = float(rng.normal(0, 150))
        u_ref, mu_ref, ok = project_halfspace_box(u0, w, g, b, lo, hi)
        u = np.empty(n)
        mu = jssa_kernels.project_halfspace_box(u0, w, g, b, lo, hi, FEAS_TOL, u)
        assert (mu < np.inf) == ok
        n_infeasible += not ok
        np.testing.assert_allclose(u, u_ref, rtol=1e-12, atol=1e-9)
        if ok:
            assert mu == pytest.approx(mu_ref, rel=1e-12, abs=1e-15)
    assert 0 < n_infeasible < 300
