"""Contact classification (Thumm et al. 2024 Sec. VI): constructed cases for every rule, brute-force
checks of the geometric predicates, and the Thm VI.2 bound against dense sampling."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from contact_reference import (
    Motion,
    classify_reference,
    closure,
    segment_box_closest,
    speed_bounds,
)
from scipy.sparse.csgraph import connected_components
from soa_reference import all_pairs

from sara_app.errors import InputError, ParameterError, UnknownNameError
from sara_app.geometry import shape_kernels
from sara_app.geometry.shape_kernels import sphere_slack_m
from sara_app.geometry.shapes import segment_box_distance, segment_segment_closest
from sara_app.robot.energy import LinkMotion
from sara_app.robot.model import load_robot
from sara_app.safety.contact import (
    ENV_CONSTRAINED,
    NONE,
    SELF_CONSTRAINED,
    UNCONSTRAINED,
    ContactClassifier,
    ContactResult,
    VelocityErrorBound,
)
from sara_app.safety.contact_kernels import classify_kernel, classify_set, source_digest
from sara_app.safety.topology import human_safe_matrix, unclampable_matrix

# A table: top face at z = 0.
TABLE_T = np.eye(4)[None].copy()
TABLE_T[0, :3, 3] = [0.0, 0.0, -0.02]
TABLE_H = np.array([[0.5, 0.5, 0.02]])
NO_BOX = (np.zeros((0, 4, 4)), np.zeros((0, 3)))
HAND_D = 0.12  # diameter used for the hands in these cases


def _x_capsule(y: float, z: float, half: float = 0.2) -> list[list[float]]:
    return [[-half, y, z], [half, y, z]]


def _classify(
    links: list[tuple[list[list[float]], float, list[float]]],
    parts: list[tuple[str, list[list[float]], float]],
    boxes: tuple[np.ndarray, np.ndarray] = (TABLE_T, TABLE_H),
    unclampable: np.ndarray | None = None,
    **flags: bool,
) -> ContactResult:
    """One interval; links (ends, radius, velocity), parts (name, ends, radius)."""
    L, P = len(links), len(parts)
    r_ends = np.array([[ln[0] for ln in links]], dtype=float)
    r_radius = np.array([[ln[1] for ln in links]])
    vel = np.array([ln[2] for ln in links], dtype=float)
    names = [p[0] for p in parts]
    clf = ContactClassifier(
        np.zeros((L, L), bool) if unclampable is None else unclampable,
        human_safe_matrix(names),
        np.full(P, HAND_D),
        **flags,
    )
    return clf.classify(
        r_ends,
        r_radius,
        np.repeat(r_ends, 2, axis=0),
        r_radius[0],
        np.repeat(vel[None], 2, axis=0),
        np.zeros((2, L, 3)),
        np.full((1, L), 1e-4),
        np.array([[p[1] for p in parts]], dtype=float),
        np.array([[p[2] for p in parts]]),
        *boxes,
    )


HAND_ON_TABLE = ("l_hand", [[0.0, 0.0, 0.05]] * 2, 0.05)


# --- constructed cases ----------------------------------------------------------------------


def test_hand_between_link_and_table_is_constrained_when_the_link_approaches() -> None:
    down = _classify([(_x_capsule(0.0, 0.13), 0.04, [0.0, 0.0, -0.1])], [HAND_ON_TABLE])
    assert down.cls[0, 0, 0] == ENV_CONSTRAINED and down.env[0, 0, 0]
    up = _classify([(_x_capsule(0.0, 0.13), 0.04, [0.0, 0.0, 0.1])], [HAND_ON_TABLE])
    assert up.cls[0, 0, 0] == UNCONSTRAINED
    sideways = _classify([(_x_capsule(0.0, 0.13), 0.04, [0.3, 0.0, 0.0])], [HAND_ON_TABLE])
    assert sideways.cls[0, 0, 0] == ENV_CONSTRAINED  # n . v = 0 < eps_v: not provably away
    no_relax = _classify(
        [(_x_capsule(0.0, 0.13), 0.04, [0.0, 0.0, 0.1])], [HAND_ON_TABLE], relax_velocity=False
    )
    assert no_relax.cls[0, 0, 0] == ENV_CONSTRAINED


def test_hand_not_touching_the_table_or_the_link() -> None:
    lifted = ("l_hand", [[0.0, 0.0, 0.07]] * 2, 0.05)  # 2 cm above the table
    res = _classify([(_x_capsule(0.0, 0.155), 0.04, [0.0, 0.0, -0.1])], [lifted])
    assert res.cls[0, 0, 0] == UNCONSTRAINED
    far = _classify([(_x_capsule(0.0, 0.5), 0.04, [0.0, 0.0, -0.1])], [HAND_ON_TABLE])
    assert far.cls[0, 0, 0] == NONE and not far.contact[0, 0, 0]


def test_link_touching_the_table_always_may_clamp() -> None:
    res = _classify([(_x_capsule(0.0, 0.03), 0.04, [0.0, 0.0, 1.0])], [HAND_ON_TABLE])
    assert res.cls[0, 0, 0] == ENV_CONSTRAINED


def test_human_diameter_relaxation() -> None:
    # A large reachable hand capsule touches the table and a link that is farther from the
    # table than the hand's diameter: no clamping possible even when the link moves down.
    big_hand = ("l_hand", [[0.0, 0.0, 0.15]] * 2, 0.15)
    link = (_x_capsule(0.0, 0.34), 0.05, [0.0, 0.0, -0.1])
    assert _classify([link], [big_hand]).cls[0, 0, 0] == UNCONSTRAINED
    assert _classify([link], [big_hand], relax_diameter=False).cls[0, 0, 0] == ENV_CONSTRAINED


FOREARM = ("l_lower_arm", [[-0.15, 0.0, 0.5], [0.15, 0.0, 0.5]], 0.04)


def _two_links(v: float) -> list[tuple[list[list[float]], float, list[float]]]:
    return [
        (_x_capsule(0.085, 0.5), 0.05, [0.0, -v, 0.0]),
        (_x_capsule(-0.085, 0.5), 0.05, [0.0, v, 0.0]),
    ]


def test_forearm_between_two_closing_links_is_self_constrained() -> None:
    res = _classify(_two_links(0.1), [FOREARM], boxes=NO_BOX)
    assert np.all(res.cls[0, :, 0] == SELF_CONSTRAINED)
    declared = np.array([[False, True], [True, False]])
    res = _classify(_two_links(0.1), [FOREARM], boxes=NO_BOX, unclampable=declared)
    assert np.all(res.cls[0, :, 0] == UNCONSTRAINED)
    res = _classify(
        _two_links(0.1), [FOREARM], boxes=NO_BOX, unclampable=declared, relax_topology=False
    )
    assert np.all(res.cls[0, :, 0] == SELF_CONSTRAINED)
    apart = _classify(_two_links(-0.1), [FOREARM], boxes=NO_BOX)
    assert np.all(apart.cls[0, :, 0] == UNCONSTRAINED)
    # Both moving the same way at the same speed: the gap does not shrink, but neither link is
    # provably faster than the other by 2 eps_v, so clamping is not excluded.
    same = [(ln[0], ln[1], [0.0, 0.1, 0.0]) for ln in _two_links(0.0)]
    assert np.all(_classify(same, [FOREARM], boxes=NO_BOX).cls[0, :, 0] == SELF_CONSTRAINED)


def test_two_hands_stacked_on_a_table_form_one_virtual_body_part() -> None:
    r_hand = ("r_hand", [[0.0, 0.0, 0.05]] * 2, 0.05)  # on the table
    l_hand = ("l_hand", [[0.0, 0.0, 0.145]] * 2, 0.05)  # on the right hand
    link = (_x_capsule(0.0, 0.24), 0.05, [0.0, 0.0, -0.1])  # touches the left hand only
    res = _classify([link], [l_hand, r_hand])
    assert res.stack[0].all()
    assert res.stack_diameter_m[0].tolist() == pytest.approx([2 * HAND_D, 2 * HAND_D])
    assert res.cls[0, 0, 0] == ENV_CONSTRAINED  # link-table gap 0.19 m <= 0.24 m
    assert res.contact[0, 0, 1] and not res.contact_single[0, 0, 1]  # r_hand is in the stack
    single = _classify([link], [l_hand, r_hand], multi_body=False)
    assert single.cls[0, 0, 0] == UNCONSTRAINED and single.cls[0, 0, 1] == NONE
    # hands from the same arm never stack: a hand and its own forearm
    forearm = ("l_lower_arm", [[0.0, 0.0, 0.05]] * 2, 0.05)
    res = _classify([link], [l_hand, forearm])
    assert not res.stack[0, 0, 1] and res.cls[0, 0, 0] == UNCONSTRAINED


def test_nan_inputs_give_the_worst_case() -> None:
    nan_part = ("l_hand", [[np.nan, 0.0, 0.0]] * 2, 0.05)
    res = _classify([(_x_capsule(0.0, 0.13), 0.04, [0.0, 0.0, -0.1])], [nan_part])
    assert res.contact[0, 0, 0] and res.cls[0, 0, 0] == ENV_CONSTRAINED
    # the human may be anywhere, but a link provably leaving the table cannot clamp
    res = _classify([(_x_capsule(0.0, 0.13), 0.04, [0.0, 0.0, 0.1])], [nan_part])
    assert res.contact[0, 0, 0] and res.cls[0, 0, 0] == UNCONSTRAINED
    nan_vel = _classify([(_x_capsule(0.0, 0.13), 0.04, [0.0, 0.0, np.nan])], [HAND_ON_TABLE])
    assert nan_vel.cls[0, 0, 0] == ENV_CONSTRAINED


# --- brute force of the predicates ----------------------------------------------------------


def _random_pose(rng: np.random.Generator) -> np.ndarray:
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    T = np.eye(4)
    T[:3, :3] = Q * np.sign(np.linalg.det(Q))
    T[:3, 3] = rng.normal(scale=0.3, size=3)
    return T


def test_segment_box_closest_against_sampling() -> None:
    rng = np.random.default_rng(0)
    nb, ns = 40, 60
    T = np.array([_random_pose(rng) for _ in range(nb)])
    h = rng.uniform(0.01, 0.4, (nb, 3))
    ends = rng.normal(scale=0.6, size=(ns, 2, 3))
    ends[:10, 1] = ends[:10, 0]  # points
    ends[10:15, 1] = ends[10:15, 0] + [0.3, 0.0, 0.0]  # axis-parallel in the world
    d, p_seg, p_box = segment_box_closest(ends, T, h)  # (ns, nb), (3, ns, nb)
    assert np.allclose(d, segment_box_distance(ends[:, None], T[None], h[None]), atol=1e-12)
    assert np.allclose(np.linalg.norm(p_seg - p_box, axis=0), d, atol=1e-12)
    local = np.einsum("bji,jsb->sbi", T[:, :3, :3], p_box - T[:, :3, 3].T[:, None, :])
    assert np.all(np.abs(local) <= h[None] + 1e-12)  # box point inside the box
    a, b = ends[:, 0, :, None], ends[:, 1, :, None]  # (ns, 3, 1)
    ps = p_seg.transpose(1, 0, 2)  # (ns, 3, nb)
    cross = np.linalg.norm(np.cross(ps - a, b - a, axis=1), axis=1)
    along = np.einsum("sib,sib->sb", ps - a, np.broadcast_to(b - a, ps.shape))
    assert np.all(cross <= 1e-9) and np.all(along >= -1e-12)  # on the segment
    u = np.linspace(0, 1, 1001)
    pts = ends[:, None, 0] + u[None, :, None] * (ends[:, 1] - ends[:, 0])[:, None]  # (ns, S, 3)
    loc = np.einsum("bji,nsbj->nsbi", T[:, :3, :3], pts[:, :, None] - T[None, None, :, :3, 3])
    brute = np.linalg.norm(np.maximum(np.abs(loc) - h, 0.0), axis=-1).min(axis=1)  # (ns, nb)
    assert np.all(d <= brute + 1e-12) and np.all(brute - d <= 2e-3)


def test_all_pairs_against_geometry_and_sampling() -> None:
    rng = np.random.default_rng(4)
    caps = rng.normal(scale=0.4, size=(3, 12, 2, 3))
    caps[:, :3, 1] = caps[:, :3, 0]  # balls
    caps[:, 3, 1] = caps[:, 3, 0] + 2 * (caps[:, 4, 1] - caps[:, 4, 0])  # parallel to 4
    d, s, t = all_pairs(caps)
    d_ref = segment_segment_closest(caps[:, :, None], caps[:, None])[0]
    off = ~np.eye(12, dtype=bool)
    assert np.allclose(d[:, off], d_ref[:, off], atol=1e-12)
    assert np.array_equal(s, t.transpose(0, 2, 1))
    pa = caps[:, :, None, 0] + s[..., None] * (caps[:, :, None, 1] - caps[:, :, None, 0])
    pb = caps[:, None, :, 0] + t[..., None] * (caps[:, None, :, 1] - caps[:, None, :, 0])
    assert np.allclose(np.linalg.norm(pa - pb, axis=-1)[:, off], d[:, off], atol=1e-12)
    u = np.linspace(0, 1, 201)
    pts = caps[:, :, None, 0] + u[None, None, :, None] * (caps[:, :, 1] - caps[:, :, 0])[:, :, None]
    brute = np.linalg.norm(pts[:, :, None, :, None] - pts[:, None, :, None, :], axis=-1)
    brute = brute.min(axis=(-1, -2))
    assert np.all(d[:, off] <= brute[:, off] + 1e-12) and np.all(brute - d <= 1e-2)


def test_thm_vi1_speed_bounds_contain_every_point_velocity() -> None:
    rng = np.random.default_rng(1)
    worst_paper = np.inf
    for _ in range(200):
        p1, p2 = rng.normal(scale=0.3, size=(2, 3))
        r = rng.uniform(0.0, 0.1)
        v1, w = rng.normal(size=3), rng.normal(scale=3.0, size=3)
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        reach = r + np.linalg.norm(p2 - p1)
        motion = Motion(
            np.tile(v1[:, None, None], (1, 2, 1)),
            np.tile(w[:, None, None], (1, 2, 1)),
            np.full((2, 1), reach),
            np.zeros((1, 1)),
        )
        lo, hi = speed_bounds(n.reshape(3, 1, 1, 1), motion)
        lam = rng.uniform(0, 1, 4000)
        u = rng.normal(size=(4000, 3))
        u *= (rng.uniform(0, 1, 4000) ** (1 / 3) * r / np.linalg.norm(u, axis=1))[:, None]
        x = p1 + lam[:, None] * (p2 - p1) + u
        vn = (v1 + np.cross(w, x - p1)) @ n
        assert vn.min() >= lo[0, 0, 0] - 1e-12 and vn.max() <= hi[0, 0, 0] + 1e-12
        paper = n @ v1 + reach * np.linalg.norm(np.cross(n, w))
        worst_paper = min(worst_paper, vn.min() - paper)
    assert worst_paper < 0.0  # the "+" printed in eq. 16/25 is not a lower bound


def test_stack_closure_matches_connected_components() -> None:
    rng = np.random.default_rng(2)
    adj = rng.uniform(size=(30, 14, 14)) < 0.08
    adj = adj | adj.transpose(0, 2, 1)
    reach = closure(adj)
    for k in range(30):
        _, label = connected_components(adj[k], directed=False)
        assert np.array_equal(reach[k], label[:, None] == label[None, :])


def test_topology_declarations_by_name() -> None:
    panda = load_robot("panda")
    G = unclampable_matrix("panda", panda.link_names)
    i3, i4, i5 = (panda.link_names.index(f"panda_link{k}") for k in (3, 4, 5))
    assert G[i3, i4] and G[i4, i3] and not G[i3, i5]  # the elbow pinch may clamp
    ur = load_robot("ur5e")
    Gu = unclampable_matrix("ur5e", ur.link_names)
    assert not Gu[ur.link_names.index("upper_arm_link"), ur.link_names.index("forearm_link")]
    # a robot without a declaration (a URDF of your own): no pair is exempt, every one may clamp
    assert not unclampable_matrix("kuka", panda.link_names).any()
    assert (unclampable_matrix("ur10e", ur.link_names) == Gu).all()
    with pytest.raises(UnknownNameError, match="'link9'"):
        unclampable_matrix("panda", panda.link_names, [("panda_link1", "link9")])
    H = human_safe_matrix(["l_hand", "l_lower_arm", "r_hand", "l_hand"], [0, 0, 0, 1])
    assert H[0, 1] and not H[0, 2] and not H[0, 3]


# --- Thm VI.2 against dense sampling --------------------------------------------------------


@pytest.mark.parametrize("name", ["panda", "ur5e"])
def test_thm_vi2_linearisation_bound_holds_on_dense_samples(name: str) -> None:
    model = load_robot(name)
    motion, bound = LinkMotion(model), VelocityErrorBound(model)
    lim = model.limits
    rng = np.random.default_rng(3)
    dt, S = 0.08, 81
    t = np.linspace(0.0, dt, S)
    ratios = []
    for _ in range(12):
        q0 = rng.uniform(np.maximum(lim.q_min, -3), np.minimum(lim.q_max, 3))
        v0 = rng.uniform(-1, 1, model.n_dof) * lim.v_max
        a0 = rng.uniform(-1, 1, model.n_dof) * lim.a_max
        j0 = rng.uniform(-1, 1, model.n_dof) * np.minimum(lim.j_max, 300.0)
        q = q0 + t[:, None] * v0 + t[:, None] ** 2 / 2 * a0 + t[:, None] ** 3 / 6 * j0
        qd = v0 + t[:, None] * a0 + t[:, None] ** 2 / 2 * j0
        qdd = a0 + t[:, None] * j0
        C = bound.coefficients(np.abs(qd).max(0), np.abs(qdd).max(0), np.abs(j0))
        C_paper = bound.coefficients(np.abs(qd).max(0), np.abs(qdd).max(0), np.abs(j0), "paper")
        eps = dt**2 / 8 * C
        smp = motion.evaluate(q, qd)
        poses = np.array([model.link_poses(qq) for qq in q])  # (S, L, 4, 4)
        # points fixed on each link: capsule ends pushed out by the radius along random dirs
        u = rng.normal(size=(model.n_links, 4, 3))
        u *= (model.radius_m[:, None] / np.linalg.norm(u, axis=-1))[..., None]
        local = np.concatenate([model.capsules_local, model.capsules_local], axis=1) + u
        x = np.einsum("slij,lpj->slpi", poses[..., :3, :3], local) + poses[:, :, None, :3, 3]
        xd = smp.p1_dot[:, :, None] + np.cross(smp.omega[:, :, None], x - smp.ends[:, :, None, 0])
        n = rng.normal(size=(8, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        vn = np.einsum("slpi,di->slpd", xd, n)  # (S, L, points, directions)
        w = (t / dt)[:, None, None, None]
        err = np.abs(vn - ((1 - w) * vn[0] + w * vn[-1])).max(axis=(0, 2, 3))  # (L,)
        assert np.all(err <= eps + 1e-12), (err, eps)
        moving = eps > 0
        ratios.append((err[moving] / eps[moving]).max())
        assert np.all(C >= C_paper - 1e-9)  # the spatial bound contains the planar one
    assert max(ratios) > 0.3  # the test trajectories do exercise the bound (seen: 0.49, 0.84)


def test_classifier_parameters_are_validated() -> None:
    with pytest.raises(ParameterError, match="human_safe has shape"):
        ContactClassifier(np.zeros((2, 2), bool), np.zeros((3, 2), bool), np.ones(3))
    with pytest.raises(ParameterError, match="expected > 0"):
        ContactClassifier(np.zeros((2, 2), bool), np.zeros((1, 1), bool), np.zeros(1))


# --- compiled classification against the numpy reference ------------------------------------


def _ref_jerk_coefficients(vb: VelocityErrorBound, qd, qdd, qddd) -> np.ndarray:
    """The spatial recursion of ``VelocityErrorBound.coefficients`` written with numpy."""
    qd, qdd, qddd = (np.abs(x) for x in np.broadcast_arrays(qd, qdd, qddd))
    W, A, Bj = np.zeros_like(qd), np.zeros_like(qd), np.zeros_like(qd)
    zero = np.zeros(qd.shape[:-1])
    for j, p in zip(vb._order, vb._parent):
        w0, a0, b0 = (zero, zero, zero) if p < 0 else (W[..., p], A[..., p], Bj[..., p])
        v, a, jj = qd[..., j], qdd[..., j], qddd[..., j]
        W[..., j] = w0 + v
        A[..., j] = a0 + a + v * w0
        Bj[..., j] = b0 + jj + 2.0 * a * w0 + v * (a0 + w0 * w0)
    return (Bj + 3.0 * A * W + W**3) @ vb._D


@pytest.mark.parametrize("name", ["panda", "ur5e"])
def test_jerk_coefficients_kernel_equals_numpy(name: str) -> None:
    vb = VelocityErrorBound(load_robot(name))
    rng = np.random.default_rng(7)
    qd, qdd, qddd = rng.normal(scale=3.0, size=(3, 5, vb.n_dof))
    C = vb.coefficients(qd, qdd, qddd)
    np.testing.assert_allclose(C, _ref_jerk_coefficients(vb, qd, qdd, qddd), rtol=1e-13)
    one = vb.coefficients(qd[0], qdd[0, 0], qddd[0])  # broadcasting, 1-D
    np.testing.assert_allclose(one, _ref_jerk_coefficients(vb, qd[0], qdd[0, 0], qddd[0]))
    qd[1, 2] = np.nan
    assert np.isnan(vb.coefficients(qd, qdd, qddd)[1]).any()


def _scene(rng: np.random.Generator) -> tuple[ContactClassifier, tuple]:
    """A random interval scene around the origin: robot and human capsules, 0-2 boxes, link
    states, topology and switches; sometimes NaN values, sometimes broadcast human capsules."""
    K, L, P, B = rng.integers(1, 5), rng.integers(2, 9), rng.integers(2, 15), rng.integers(0, 3)
    spread = rng.choice([0.2, 0.5, 1.0])
    r0 = rng.normal(scale=spread, size=(K, L, 3))
    r_ends = np.stack([r0, r0 + rng.normal(scale=0.2, size=(K, L, 3))], axis=2)
    r_radius = rng.uniform(0.02, 0.12, (K, L))
    s_ends = np.concatenate([r_ends, r_ends[-1:]]) + rng.normal(scale=0.01, size=(K + 1, L, 2, 3))
    p1_dot = rng.normal(scale=rng.choice([0.05, 0.5]), size=(K + 1, L, 3))
    omega = rng.normal(scale=rng.choice([0.1, 2.0]), size=(K + 1, L, 3))
    eps = rng.uniform(0.0, 0.05, (K, L))
    Kh = 1 if rng.random() < 0.3 else K
    h0 = rng.normal(scale=spread, size=(Kh, P, 3))
    h_ends = np.stack([h0, h0 + rng.normal(scale=0.15, size=(Kh, P, 3))], axis=2)
    h_radius = rng.uniform(0.03, 0.15, (Kh, P))
    if Kh == K and rng.random() < 0.3:
        h_ends[1:] = h_ends[0]  # static axes, growing radii (the R_VEL / R_POS sets)
    if Kh == 1 and K > 1:
        h_ends = np.broadcast_to(h_ends, (K, P, 2, 3))
        h_radius = np.broadcast_to(h_radius, (K, P))
    T = np.array([_random_pose(rng) for _ in range(B)]).reshape(B, 4, 4)
    half = rng.uniform(0.02, 0.5, (B, 3))
    if rng.random() < 0.2:  # NaN somewhere: worst case, identical in both implementations
        which = rng.integers(4)
        arr = (r_ends, s_ends, p1_dot, omega)[which]
        arr[tuple(rng.integers(s) for s in arr.shape)] = np.nan
    unclamp = rng.random((L, L)) < 0.3
    safe = rng.random((P, P)) < 0.3
    clf = ContactClassifier(
        unclamp | unclamp.T,
        safe | safe.T,
        rng.uniform(0.05, 0.3, P),
        relax_velocity=rng.random() < 0.8,
        relax_diameter=rng.random() < 0.8,
        relax_topology=rng.random() < 0.8,
        multi_body=rng.random() < 0.8,
    )
    args = (r_ends, r_radius, s_ends, r_radius[0] * 0.8, p1_dot, omega, eps, h_ends, h_radius)
    return clf, args + (T, half)


def test_compiled_classify_equals_the_numpy_reference() -> None:
    rng = np.random.default_rng(11)
    n_contact = n_clamped = 0
    for _ in range(300):
        clf, args = _scene(rng)
        fast, ref = clf.classify(*args), classify_reference(clf, *args)
        for name in ("contact", "contact_single", "env", "self_", "cls", "stack"):
            assert np.array_equal(getattr(fast, name), getattr(ref, name)), name
        np.testing.assert_allclose(fast.stack_diameter_m, ref.stack_diameter_m, rtol=1e-14)
        # the PFL verdict's summary reads the contacts off the classes
        assert np.array_equal(ref.contact, ref.cls > 0)
        # exact where a pair may touch, else a positive lower bound (bounding spheres)
        near = ~(ref.distance_m > sphere_slack_m)
        np.testing.assert_allclose(fast.distance_m[near], ref.distance_m[near], atol=1e-12)
        assert np.all(fast.distance_m[~near] > 0)
        assert np.all(fast.distance_m[~near] <= ref.distance_m[~near] + 1e-12)
        n_contact += bool(ref.contact.any())
        n_clamped += bool((ref.cls >= ENV_CONSTRAINED).any() and (ref.cls == UNCONSTRAINED).any())
    assert n_contact > 150 and n_clamped > 30  # the scenes exercise every branch


def test_classify_rejects_shapes_the_kernels_cannot_index() -> None:
    rng = np.random.default_rng(12)
    clf, args = _scene(rng)
    bad = list(args)
    bad[6] = bad[6][:, :-1]  # eps_v with one link missing
    with pytest.raises(InputError, match=r"eps_v has shape .* intervals, L = "):
        clf.classify(*bad)
    bad = list(args)
    bad[10] = bad[10][:, :2]  # half extents of the boxes without z
    with pytest.raises(InputError, match=r"half_extents_m has shape .* links, B boxes"):
        clf.classify(*bad)


def test_classify_humans_over_a_range_equals_classify_of_the_slice() -> None:
    """The shield's path: the robot side validated once, human sets per interval range (and
    static axes with growing radii given as ``(1, P, 2, 3)`` ends) give exactly what
    :meth:`ContactClassifier.classify` gives for the sliced, broadcast inputs."""
    rng = np.random.default_rng(13)
    ranged = 0
    for _ in range(120):
        clf, args = _scene(rng)
        r_ends, r_radius, s_ends, s_radius, p1_dot, omega, eps, h_ends, h_radius, T, half = args
        K = r_radius.shape[0]
        robot = clf.robot_side(r_ends, r_radius, s_ends, s_radius, p1_dot, omega, eps, T, half)
        lo = int(rng.integers(0, K))
        hi = int(rng.integers(lo + 1, K + 1))
        k = hi - lo
        he, hr = np.asarray(h_ends)[lo:hi], np.asarray(h_radius)[lo:hi]
        static = rng.random() < 0.5
        if static:  # one set of axes for every interval, radii per interval
            he = np.broadcast_to(he[:1], he.shape)
        fast = clf.classify_humans(robot, he[:1] if static else he, hr, lo, hi)
        ref = clf.classify(
            r_ends[lo:hi], r_radius[lo:hi], s_ends[lo : hi + 1], s_radius,
            p1_dot[lo : hi + 1], omega[lo : hi + 1], eps[lo:hi], np.ascontiguousarray(he),
            np.ascontiguousarray(hr), T, half,
        )  # fmt: skip
        for name in ("contact", "contact_single", "env", "self_", "cls", "stack"):
            assert np.array_equal(getattr(fast, name), getattr(ref, name)), name
        np.testing.assert_array_equal(fast.distance_m, ref.distance_m)
        assert fast.cls.shape[0] == k
        ranged += k < K
        # a second human set against the same robot side (its clamping caches now filled)
        he2 = np.ascontiguousarray(he) + rng.normal(scale=0.1, size=he.shape)
        hr2 = np.ascontiguousarray(hr) * rng.uniform(0.5, 2.0)
        again = clf.classify_humans(robot, he2, hr2, lo, hi)
        fresh = clf.classify(
            r_ends[lo:hi], r_radius[lo:hi], s_ends[lo : hi + 1], s_radius,
            p1_dot[lo : hi + 1], omega[lo : hi + 1], eps[lo:hi], he2, hr2, T, half,
        )  # fmt: skip
        for name in ("contact", "env", "self_", "cls", "stack"):
            assert np.array_equal(getattr(again, name), getattr(fresh, name)), name
    assert ranged > 30
    with pytest.raises(InputError, match="interval range"):
        clf.classify_humans(robot, h_ends, h_radius, 0, K + 1)
    other, _ = _scene(rng)
    with pytest.raises(InputError, match="another classifier"):
        other.classify_humans(robot, h_ends, h_radius)


def test_virtual_body_parts_follow_radii_that_grow_on_fixed_axes() -> None:
    """Sets with fixed axes and radii that grow per interval (R_POS, R_VEL), given as ``(1, P,
    2, 3)`` ends: parts apart on the first interval merge into virtual body parts as they
    grow, exactly as with the ends repeated for every interval (the human-human distances'
    broad phase is made ready for each interval's radii, not only for new axes)."""
    rng = np.random.default_rng(5)
    merged = 0
    for _ in range(60):
        clf, args = _scene(rng)
        r_ends, r_radius, s_ends, s_radius, p1_dot, omega, eps, h_ends, h_radius, T, half = args
        K, P = r_radius.shape[0], h_radius.shape[-1]
        if K < 2 or not clf.multi_body:
            continue
        he = np.ascontiguousarray(np.asarray(h_ends)[:1])
        hr = np.outer(np.linspace(0.01, 0.5, K), np.ones(P))
        robot = clf.robot_side(r_ends, r_radius, s_ends, s_radius, p1_dot, omega, eps, T, half)
        fast = clf.classify_humans(robot, he, hr)
        ref = clf.classify(
            r_ends, r_radius, s_ends, s_radius, p1_dot, omega, eps, np.repeat(he, K, axis=0),
            hr, T, half,
        )  # fmt: skip
        assert np.array_equal(fast.stack, ref.stack)
        merged += int(fast.stack[-1].sum() > fast.stack[0].sum())
    assert merged > 5


@pytest.mark.parametrize("kernel", [classify_set, classify_kernel])
def test_classify_cache_keys_carry_the_geometry_kernels_source(kernel: Any) -> None:
    """numba's cache checks only the kernel's own file; classify_set and classify_kernel call
    the geometry kernels, so their closures (hashed into numba's cache key) must hold their
    source digest."""
    cells = [c.cell_contents for c in kernel.py_func.__closure__ or ()]
    assert source_digest(shape_kernels) in cells
