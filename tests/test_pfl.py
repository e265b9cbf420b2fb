"""The PFL verdict (Thumm et al. 2024 eq. 6-7, 47-48) on the Panda with a full-body human."""

from __future__ import annotations

import numpy as np
import pytest
from pfl_reference import merged

from sara_app.bench.pfl import check_rows
from sara_app.errors import InputError
from sara_app.human.skeleton import skeleton
from sara_app.robot.energy import bounded_interval_energy_J
from sara_app.robot.model import load_robot
from sara_app.safety.contact import ENV_CONSTRAINED, NONE, UNCONSTRAINED
from sara_app.safety.pfl import PflCheck, PflResult

PARTS = skeleton("full").parts
Q0 = np.array([0.0, 0.3, 0.0, -2.0, 0.0, 2.3, 0.8])
DT = 1e-3


@pytest.fixture(scope="module")
def pfl() -> PflCheck:
    return PflCheck(load_robot("panda"), PARTS)


def _far_human(K: int) -> tuple[np.ndarray, np.ndarray]:
    h_ends = np.zeros((K, len(PARTS), 2, 3))
    h_ends[..., 0] = 5.0 + np.arange(len(PARTS))[None, :, None]  # x far away, spread out
    return h_ends, np.full((K, len(PARTS)), 0.1)


def _run(
    pfl: PflCheck,
    q_dot: np.ndarray,
    h: tuple[np.ndarray, np.ndarray],
    boxes: tuple[np.ndarray, np.ndarray],
    K: int = 1,
) -> PflResult:
    t = np.arange(K + 1) * DT
    q = Q0 + t[:, None] * q_dot
    qd = np.broadcast_to(q_dot, q.shape)
    bound = np.broadcast_to(np.abs(q_dot), (K, 7))
    return pfl.check_trajectory(q, qd, bound, t, *h, *boxes, qdd_bound=np.zeros((K, 7)))


def _hand_on_table(pfl: PflCheck) -> tuple[tuple, tuple, np.ndarray, int]:
    """A hand ball under the Panda hand, resting on a table 10 cm below the link."""
    model = pfl.model
    ends, radius = model.link_capsules(Q0)
    i_hand = model.link_names.index("panda_hand")
    low = ends[i_hand][np.argmin(ends[i_hand, :, 2])]
    z_top = low[2] - radius[i_hand] - 0.10
    T = np.eye(4)[None].copy()
    T[0, :3, 3] = [low[0], low[1], z_top - 0.02]
    h_ends, h_radius = _far_human(1)
    j = PARTS.index("l_hand")
    h_ends[0, j] = [low[0], low[1], z_top + 0.051]
    h_radius[0, j] = 0.051
    # joint velocity moving the hand link straight down at 1 m/s
    J = model.link_jacobians(Q0)[i_hand]
    q_dot = np.linalg.pinv(J) @ np.array([0.0, 0.0, -1.0, 0.0, 0.0, 0.0])
    return (h_ends, h_radius), (T, np.array([[0.5, 0.5, 0.02]])), q_dot, i_hand


def test_hand_on_table_energy_between_the_thresholds(pfl: PflCheck) -> None:
    human, table, q_dot, i = _hand_on_table(pfl)
    j = PARTS.index("l_hand")
    E1 = pfl.motion.energies(Q0[None], q_dot[None])[0, i]
    q_dot = q_dot * np.sqrt(0.3 / E1)  # hand link energy 0.3 J: 0.12 (clamp) < 0.3 < 0.49 (free)
    down = _run(pfl, q_dot, human, table)
    assert down.cls[0, i, j] == ENV_CONSTRAINED
    assert down.threshold_J[0, i, j] == 0.12
    assert down.energy_J[0, i] == pytest.approx(0.3, rel=0.02)
    assert down.allowed_J[0, i] == 0.12 and down.limiting_part[0, i] == j
    assert not down.safe[0, i, j] and not down.safe_all
    up = _run(pfl, -q_dot, human, table)
    assert up.cls[0, i, j] == UNCONSTRAINED
    assert up.threshold_J[0, i, j] == 0.49 and up.safe[0, i, j]
    assert up.margin_J[0, i, j] == pytest.approx(0.49 - up.energy_J[0, i])
    no_table = _run(pfl, q_dot, human, (np.zeros((0, 4, 4)), np.zeros((0, 3))))
    assert no_table.cls[0, i, j] == UNCONSTRAINED and no_table.safe[0, i, j]


def test_far_human_and_robot_at_rest_are_safe(pfl: PflCheck) -> None:
    boxes = (np.zeros((0, 4, 4)), np.zeros((0, 3)))
    far = _run(pfl, np.full(7, 1.5), _far_human(3), boxes, K=3)
    assert far.safe_all and np.all(far.cls == NONE)
    assert np.all(np.isinf(far.allowed_J)) and np.all(far.limiting_part == -1)
    h_ends = np.zeros((3, len(PARTS), 2, 3))
    h_ends[..., 2] = 0.5
    engulf = (h_ends, np.full((3, len(PARTS)), 3.0))
    rest = _run(pfl, np.zeros(7), engulf, boxes, K=3)
    assert rest.safe_all and np.all(rest.contact.contact)  # zero energy: contact is harmless
    fast = _run(pfl, np.full(7, 1.5), engulf, boxes, K=3)
    assert not fast.safe_all
    moving = fast.energy_J[:, :, None] > 0
    assert np.array_equal(fast.safe, fast.energy_J[:, :, None] < fast.threshold_J)
    assert np.any(~fast.safe & moving)


def test_applied_threshold_follows_class_stack_and_tool_shape() -> None:
    model = load_robot("panda")
    pfl = PflCheck(model, PARTS, link_shapes={"panda_hand": "edge"})
    i_hand = model.link_names.index("panda_hand")
    assert pfl.T_free[i_hand, PARTS.index("l_hand")] == 0.375
    assert pfl.T_free[0, PARTS.index("l_hand")] == 0.49  # other links blunt
    rng = np.random.default_rng(0)
    K = 4
    h_ends = rng.normal(scale=0.5, size=(K, len(PARTS), 2, 3)) + [0.4, 0.0, 0.4]
    h_radius = rng.uniform(0.02, 0.05, (K, len(PARTS)))
    T = np.eye(4)[None].copy()
    T[0, :3, 3] = [0.5, 0.0, 0.2]
    res = _run(pfl, rng.uniform(-1, 1, 7), (h_ends, h_radius), (T, np.array([[0.3, 0.3, 0.1]])), K)
    assert set(np.unique(res.cls).tolist()) >= {NONE, UNCONSTRAINED, ENV_CONSTRAINED}
    for k, i, j in zip(*np.nonzero(res.cls >= ENV_CONSTRAINED)):
        members = np.flatnonzero(res.contact.stack[k, j])
        assert res.threshold_J[k, i, j] == pfl.T_clamp[i, members].min()
    free = res.cls <= UNCONSTRAINED
    assert np.array_equal(res.threshold_J[free], np.broadcast_to(pfl.T_free, res.cls.shape)[free])


def test_check_matches_check_trajectory_and_energy_forms(pfl: PflCheck) -> None:
    rng = np.random.default_rng(1)
    K = 3
    t = np.arange(K + 1) * 0.004
    q = Q0 + rng.normal(scale=0.02, size=(K + 1, 7))
    qd = rng.uniform(-1, 1, (K + 1, 7))
    bound = np.maximum(np.abs(qd[:-1]), np.abs(qd[1:])) + np.abs(np.diff(q, axis=0)) / 0.004
    h = (rng.normal(scale=0.3, size=(K, len(PARTS), 2, 3)) + 0.4, np.full((K, len(PARTS)), 0.1))
    boxes = (np.eye(4)[None], np.array([[0.2, 0.2, 0.05]]))
    a = pfl.check_trajectory(q, qd, bound, t, *h, *boxes)
    r_ends, r_radius = pfl.occupancy.intervals(q, bound, t)
    s = pfl.motion.evaluate(q, qd)
    eps = pfl.eps_from_bounds(np.diff(t), bound)
    args = (r_ends, r_radius, s.ends, s.p1_dot, s.omega, np.diff(t), *h, *boxes)
    E_int = bounded_interval_energy_J(pfl.motion, q, s.energy_J, np.broadcast_to(
        pfl.model.limits.a_max, (K, 7)), np.diff(t))  # fmt: skip
    assert np.all(E_int >= np.maximum(s.energy_J[:-1], s.energy_J[1:]))
    b = pfl.check(*args, E_int, eps_v=eps)
    ends_form = pfl.check(*args, s.energy_J.copy(), eps_v=eps)
    c = pfl.check(*args, np.stack([s.energy_J[:-1], s.energy_J[1:]], axis=1), eps_v=eps)
    assert np.array_equal(ends_form.margin_J, c.margin_J)
    h1 = (h[0][:1], h[1][:1])  # one human occupancy for every interval, broadcast
    d = pfl.check(*args[:6], *h1, *boxes, s.energy_J, eps_v=eps)
    e = pfl.check(*args[:6], np.repeat(h1[0], K, 0), np.repeat(h1[1], K, 0), *boxes,
                  s.energy_J, eps_v=eps)  # fmt: skip
    assert np.array_equal(d.cls, e.cls) and np.array_equal(d.margin_J, e.margin_J)
    assert np.array_equal(a.safe, b.safe) and np.array_equal(a.cls, b.cls)
    assert np.array_equal(a.margin_J, b.margin_J) and np.array_equal(a.cls, c.cls)
    with pytest.raises(InputError, match="h_radius has shape"):
        pfl.check(*args[:7], h[1][:, :3], *boxes, s.energy_J)
    with pytest.raises(InputError, match="energy_J has shape"):
        pfl.check(*args, s.energy_J[:2])


def test_non_finite_trajectory_is_unsafe_without_raising(pfl: PflCheck) -> None:
    K = 2
    t = np.arange(K + 1) * DT
    q = np.tile(Q0, (K + 1, 1))
    qd = np.full((K + 1, 7), 0.5)
    q[1, 3] = np.nan
    h_ends, h_radius = _far_human(K)
    res = pfl.check_trajectory(q, qd, np.full((K, 7), 0.5), t, h_ends, h_radius,
                               np.zeros((0, 4, 4)), np.zeros((0, 3)))  # fmt: skip
    assert not res.safe_all and np.all(res.contact.contact)


def test_bench_rows_shape() -> None:
    rows = check_rows(3)
    assert len(rows) == 5
    for name, med, p99, note in rows:
        assert name.startswith("pfl") and med > 0 and p99 >= med and "Panda" in note


def _ref_verdict(pfl: PflCheck, c, E_int: np.ndarray) -> tuple[np.ndarray, ...]:
    """Eq. 7 and the per-link allowed energy written with numpy (the implementation before the
    compiled verdict)."""
    clamped = c.cls >= 2
    T_clamp = np.where(c.stack[:, None, :, :], pfl.T_clamp[None, :, None, :], np.inf).min(-1)
    thr = np.where(clamped, T_clamp, pfl.T_free[None])
    margin = thr - E_int[:, :, None]
    safe = ~c.contact | (margin > 0.0)
    thr_contact = np.where(c.contact, thr, np.inf)
    part = np.argmin(thr_contact, axis=2)
    allowed = np.take_along_axis(thr_contact, part[..., None], axis=2)[..., 0]
    part = np.where(np.isfinite(allowed), part, -1)
    return safe, safe.all(axis=(1, 2)), thr, margin, allowed, part


def test_compiled_verdict_equals_the_numpy_formula() -> None:
    model = load_robot("panda")
    pfl = PflCheck(model, PARTS, link_shapes={"panda_hand": "edge"})
    rng = np.random.default_rng(3)
    seen_clamped = 0
    for trial in range(40):
        K = int(rng.integers(1, 5))
        h_ends = rng.normal(scale=0.4, size=(K, len(PARTS), 2, 3)) + [0.4, 0.0, 0.4]
        h_radius = rng.uniform(0.02, 0.1, (K, len(PARTS)))
        T = np.eye(4)[None].copy()
        T[0, :3, 3] = [0.5, 0.0, rng.uniform(0.0, 0.4)]
        res = _run(pfl, rng.uniform(-1.5, 1.5, 7), (h_ends, h_radius),
                   (T, np.array([[0.3, 0.3, 0.1]])), K)  # fmt: skip
        E = res.energy_J.copy()
        if trial % 5 == 0:
            E[0, rng.integers(E.shape[1])] = np.nan  # NaN energy: unsafe where in contact
        got = pfl._verdict(res.contact, E)
        safe, safe_k, thr, margin, allowed, part = _ref_verdict(pfl, res.contact, E)
        assert np.array_equal(got.safe, safe) and np.array_equal(got.safe_interval, safe_k)
        assert np.array_equal(got.threshold_J, thr) and np.array_equal(got.allowed_J, allowed)
        np.testing.assert_array_equal(got.margin_J, margin)
        assert np.array_equal(got.limiting_part, part) and got.safe_all == bool(safe_k.all())
        seen_clamped += int((res.cls >= 2).any())
    assert seen_clamped > 5


def test_check_trajectory_energy_covers_the_motion_between_samples(pfl: PflCheck) -> None:
    """Soundness of :meth:`PflCheck.check_trajectory`'s interval energy: along trajectories of
    bounded acceleration (a cubic per joint, ``|q''|`` bounded per interval by the larger end
    value since ``q''`` is linear), densely sampled link energies stay below it, while the end
    samples alone (eq. 47-48) miss energy."""
    rng = np.random.default_rng(5)
    missed = 0.0
    for _ in range(20):
        K = int(rng.integers(1, 4))
        T = rng.uniform(0.01, 0.05) * K
        c = rng.normal(size=(4, 7)) * [[0.3], [1.0], [4.0], [30.0]]
        c[0] += Q0

        def motion(tt: np.ndarray, c: np.ndarray = c) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            tt = tt[:, None]
            q = c[0] + tt * (c[1] + tt * (c[2] + tt * c[3]))
            return q, c[1] + tt * (2 * c[2] + 3 * tt * c[3]), 2 * c[2] + 6 * tt * c[3]

        t = np.linspace(0.0, T, K + 1)
        q, qd, qdd = motion(t)
        qdd_bound = np.maximum(np.abs(qdd[:-1]), np.abs(qdd[1:]))
        E_s = pfl.motion.evaluate(q, qd).energy_J.copy()
        bound = bounded_interval_energy_J(pfl.motion, q, E_s, qdd_bound, np.diff(t))
        for k in range(K):
            qq, vv, _ = motion(np.linspace(t[k], t[k + 1], 60))
            dense = pfl.motion.energies(qq, vv).max(axis=0)
            assert np.all(dense <= bound[k] + 1e-12), (k, dense / bound[k])
            missed = max(missed, float(np.max(dense - np.maximum(E_s[k], E_s[k + 1]))))
    assert missed > 0.0


def _ref_merge(results: list[tuple[PflResult, int, int]]) -> tuple[np.ndarray, ...]:
    """The per-entry model merge written with numpy (the implementation before the compiled
    merge): an entry takes the first proving model's class and threshold; an unproved one the
    highest threshold seen."""
    first = results[0][0]
    safe, cls, thr = first.safe.copy(), first.cls.copy(), first.threshold_J.copy()
    for r, lo, hi in results[1:]:
        old = safe[lo:hi]
        take = (r.safe & ~old) | (~old & ~r.safe & (r.threshold_J > thr[lo:hi]))
        cls[lo:hi] = np.where(take, r.cls, cls[lo:hi])
        thr[lo:hi] = np.where(take, r.threshold_J, thr[lo:hi])
        safe[lo:hi] = old | r.safe
    thr_contact = np.where(cls > 0, thr, np.inf)
    part = np.argmin(thr_contact, axis=2)
    allowed = np.take_along_axis(thr_contact, part[..., None], axis=2)[..., 0]
    part = np.where(np.isfinite(allowed), part, -1)
    return safe, cls, thr, allowed, part


def test_merged_check_equals_the_numpy_merge_of_single_model_checks() -> None:
    model = load_robot("panda")
    pfl = PflCheck(model, PARTS, link_shapes={"panda_hand": "edge"})
    rng = np.random.default_rng(4)
    merged_models = 0
    for _ in range(40):
        K = int(rng.integers(1, 6))
        t = np.arange(K + 1) * 0.005
        q_dot = rng.uniform(-1.5, 1.5, 7)
        q = Q0 + t[:, None] * q_dot
        qd = np.broadcast_to(q_dot, q.shape)
        bound = np.broadcast_to(np.abs(q_dot), (K, 7))
        r_ends, r_radius = pfl.occupancy.intervals(q, bound, t)
        smp = pfl.motion.evaluate(q, qd)
        E = np.maximum(smp.energy_J[:-1], smp.energy_J[1:]) * rng.uniform(0.5, 3.0)
        eps = pfl.eps_from_bounds(np.diff(t), bound)
        T = np.eye(4)[None].copy()
        T[0, :3, 3] = [0.5, 0.0, rng.uniform(0.0, 0.4)]
        boxes = (T, np.array([[0.3, 0.3, 0.1]]))
        base = rng.normal(scale=0.3, size=(K, len(PARTS), 2, 3)) + [0.4, 0.0, 0.4]
        check = merged(pfl, r_ends, r_radius, smp, np.diff(t), eps, *boxes, E)
        singles = []
        for m in range(3):  # nested sets: every model sound for the same person
            lo, hi = check.todo
            if lo >= hi:
                break
            radius = rng.uniform(0.02, 0.08, (K, len(PARTS))) + 0.1 * (2 - m)
            args = (r_ends, r_radius, smp.ends, smp.p1_dot, smp.omega, np.diff(t))
            single = pfl.check(*args, base, radius, *boxes, E, eps_v=eps)
            singles.append((PflResult(*(
                getattr(single, f)[lo:hi] if f in ("safe", "cls", "threshold_J") else
                getattr(single, f) for f in PflResult.__dataclass_fields__
            )), lo, hi))  # fmt: skip
            check.add(base[lo:hi], radius[lo:hi])
        res = check.result()
        safe, cls, thr, allowed, part = _ref_merge(singles)
        assert np.array_equal(res.safe, safe) and np.array_equal(res.cls, cls)
        assert np.array_equal(res.threshold_J, thr) and np.array_equal(res.allowed_J, allowed)
        assert np.array_equal(res.limiting_part, part)
        np.testing.assert_array_equal(res.margin_J, thr - E[:, :, None])
        assert np.array_equal(res.safe_interval, safe.all(axis=(1, 2)))
        assert res.safe_all == bool(safe.all())
        bad = np.flatnonzero(~safe.all(axis=(1, 2)))
        assert check.todo == ((int(bad[0]), int(bad[-1]) + 1) if bad.size else (K, K))
        merged_models += len(singles) > 1
    assert merged_models > 10
