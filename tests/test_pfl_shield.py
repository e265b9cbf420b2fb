"""The PFL shield (``sara_app.safety.pfl_shield``): per-entry "any model" merge equals the OR of
the single-model verdicts; the rules it rests on are monotone in the human sets (sampled);
every body part lies in the capsule a model gives it; only verified steps are committed, else
the robot brakes exactly along the held failsafe; near a person it slows instead of stopping;
nobody: full speed; faults and numeric failures brake, never raise; a robot at rest verifies.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from pfl_reference import ReferencePflShield, allowed_speed, as_reference, candidate, merged

from sara_app.cell.build import build_cell
from sara_app.errors import ParameterError
from sara_app.geometry.shapes import points_in_capsules
from sara_app.human.scripted import joints, standing
from sara_app.robot.trajectory import JointState
from sara_app.safety.pfl_shield import PflShield, part_capsules
from sara_app.safety.shield import HumanState
from sara_app.scenario import parse_scenario

TABLE = {"name": "table", "center_m": [0.65, 0.0, 0.1], "size_m": [0.5, 1.6, 0.2]}
Q = [0.3, 0.0, -1.8, 0.0, 2.1, 0.8]


def make_shield(
    models: tuple[str, ...] = ("acc", "vel", "pos"), env: bool = True, **pfl: object
) -> PflShield:
    sc = parse_scenario(
        {
            "name": "t",
            "task": {"waypoints_rad": [[-0.8, *Q], [0.8, *Q]]},
            "environment": [TABLE] if env else [],
            "shield": {"mode": "pfl", "models": list(models), "pfl": pfl},
            "human_params": "schepp2022_table1",  # the people below are placed for its sets
        }
    )
    shield = build_cell(sc).shield
    assert isinstance(shield, PflShield)
    return shield


def reference_shield(models: tuple[str, ...] = ("acc", "vel", "pos")) -> ReferencePflShield:
    """The shield composed in Python (tests/pfl_reference.py): its checks are reachable one by
    one, and the production shield equals it cycle by cycle (tests/test_pfl_fused_kernels.py)."""
    return as_reference(make_shield(models))


def person(x: float, y: float, stamp: float, hid: str = "p") -> HumanState:
    yj = joints(standing((x, y), math.atan2(-y, -x)))
    return HumanState(hid, yj, np.zeros_like(yj), np.full(len(yj), 0.05), stamp)


def run_free(shield: PflShield, n: int) -> float:
    """``n`` cycles with nobody in the cell (the robot speeds up); returns the time."""
    t = 0.0
    for _ in range(n):
        shield.cycle(t, [])
        t += shield.settings.dt_s
    return t


def hum_arrays(shield: PflShield, people: list[HumanState], t: float):
    ages = {p.id: t - float(p.stamp_s) for p in people}  # type: ignore[arg-type]
    return shield._human_arrays(people, list(range(len(people))), ages)


def test_any_model_merge_is_the_or_of_single_model_verdicts() -> None:
    shield = reference_shield()
    t = run_free(shield, 60)
    hum = hum_arrays(shield, [person(0.85, 0.0, t)], t)
    traj, ends, radius = shield._plan(math.inf)
    res, used, _ = shield._verify(traj, ends, radius, hum)
    K = len(traj.times) - 1
    smp, energy, eps = shield._link_energies(traj)
    any_safe = np.zeros_like(res.safe)
    for name in shield.settings.models:
        h_e, h_r = shield._human_sets(name, hum, traj.times, 0, K)
        r = shield.pfl.check(
            ends, radius, smp.ends, smp.p1_dot, smp.omega, np.diff(traj.times), h_e, h_r,
            *shield.boxes, energy, eps_v=eps,
        )  # fmt: skip
        any_safe |= r.safe
    np.testing.assert_array_equal(res.safe, any_safe)
    assert (~res.safe).any() and used >= 2  # the case is not trivial
    np.testing.assert_array_equal(res.safe_interval, any_safe.all(axis=(1, 2)))


@pytest.mark.parametrize(("x", "possible"), [(0.85, True), (1.4, True), (3.0, False)])
def test_deferred_energies_change_no_verdict(x: float, possible: bool) -> None:
    """The check obtains the link energies and twists only when a human set may touch a link:
    its verdict and classes equal the eager check's (all models, every entry); without a
    possible contact it never evaluates them and says so, and ``with_energies`` fills them
    (for the display) equal to the eager check's; the compiled cycle's ``energy_known`` is the
    same."""
    shield = reference_shield()
    compiled = make_shield()
    t = run_free(shield, 60)
    hum = hum_arrays(shield, [person(x, 0.0, t)], t)
    traj, ends, radius = shield._plan(math.inf)
    calls = []
    real = shield._link_energies
    shield._link_energies = lambda tr: calls.append(1) or real(tr)  # type: ignore[method-assign]
    res, used, _ = shield._verify(traj, ends, radius, hum)
    del shield._link_energies
    K = len(traj.times) - 1
    dt = np.diff(traj.times)
    smp, energy, eps = shield._link_energies(traj)
    eager = merged(shield.pfl, ends, radius, smp, dt, eps, *shield.boxes, energy)
    for m in shield._model_order[:used]:
        lo, hi = eager.todo
        if lo >= hi:
            break
        h_e, h_r = shield._human_sets(m, hum, traj.times, lo, hi)
        eager.add(h_e, h_r)
    ref = eager.result()
    assert bool(res.contact.contact.any()) == possible  # the case is what it says
    assert len(calls) == int(possible) and res.energy_known == possible
    run_free(compiled, 60)
    assert compiled.cycle(t, [person(x, 0.0, t)]).pfl.energy_known == possible  # type: ignore[union-attr]
    for name in ("safe", "cls", "threshold_J", "allowed_J", "limiting_part"):
        np.testing.assert_array_equal(getattr(res, name), getattr(ref, name), err_msg=name)
    filled = shield.with_energies(res, traj)
    assert filled.energy_known
    np.testing.assert_array_equal(filled.energy_J, ref.energy_J)
    np.testing.assert_array_equal(filled.margin_J, ref.margin_J)
    if not possible:
        assert np.isnan(res.energy_J).all() and res.safe_all
        assert np.isfinite(filled.energy_J).all() and filled.energy_J.max() > 0  # it moves
    else:
        assert filled is res
    assert K == res.energy_J.shape[0]


def test_model_order_changes_the_work_not_the_verdict() -> None:
    """Every order of the models proves the same entries safe; after a completed check the
    model that completed it is tried first."""
    from itertools import permutations

    shield = reference_shield()
    t = run_free(shield, 60)
    moved = failed = 0
    for x in (0.85, 1.1, 1.4):  # failing, and (further away) completing checks
        hum = hum_arrays(shield, [person(x, 0.0, t)], t)
        traj, ends, radius = shield._plan(math.inf)
        verdicts = []
        for order in permutations(("acc", "vel", "pos")):
            shield._model_order = list(order)
            res, used, _ = shield._verify(traj, ends, radius, hum)
            verdicts.append(res.safe)
            if res.safe_all:
                assert shield._model_order[0] == order[used - 1]
                assert sorted(shield._model_order) == ["acc", "pos", "vel"]
                moved += used > 1
            else:
                failed += 1
                assert shield._model_order == list(order)  # a failed check keeps the order
        for v in verdicts[1:]:
            np.testing.assert_array_equal(v, verdicts[0])
    assert moved and failed


def test_a_lazy_check_is_conservative_and_finishes_to_the_full_one() -> None:
    """``first_only`` stops a failing check after one model: it proves a subset of what every
    model proves; finishing it adds the other models and gives the full check."""
    shield = reference_shield()
    t = run_free(shield, 60)
    hum = hum_arrays(shield, [person(0.85, 0.0, t)], t)
    traj, ends, radius = shield._plan(math.inf)
    for first in ("acc", "vel", "pos"):
        order = [first] + [m for m in ("acc", "vel", "pos") if m != first]
        shield._model_order = list(order)
        full, used_full, _ = shield._verify(traj, ends, radius, hum)
        assert not full.safe_all and used_full == 3
        shield._model_order = list(order)
        lazy, used, _ = shield._verify(traj, ends, radius, hum, first_only=True)
        assert used == 1 and not lazy.safe_all
        assert not (lazy.safe & ~full.safe).any()  # nothing proved that the full check does not
        done, used, _ = shield._finish_check()
        assert used == 3
        np.testing.assert_array_equal(done.safe, full.safe)


def test_a_check_that_a_replan_can_follow_stops_only_for_the_replan() -> None:
    """``replan = (cap, c_min)``: a failing first model stops the check exactly when the lazy
    result is fixable and its next cap (``_next_cap``) reaches ``c_min``; otherwise the check
    goes on to the full one (the same result as finishing a lazy check)."""
    shield = reference_shield()
    t = run_free(shield, 60)
    hum = hum_arrays(shield, [person(0.85, 0.0, t)], t)
    traj, ends, radius = shield._plan(math.inf)
    stops = []
    for first in ("acc", "vel", "pos"):
        order = [first] + [m for m in ("acc", "vel", "pos") if m != first]
        shield._model_order = list(order)
        lazy, _, E0 = shield._verify(traj, ends, radius, hum, first_only=True)
        cand, fixable = shield._next_cap(lazy, traj, E0.copy(), math.inf, True)
        lazy_safe, lazy_thr = lazy.safe.copy(), lazy.threshold_J.copy()  # finishing merges in
        full, _, _ = shield._finish_check()
        for c_min in (0.0, 0.5 * cand, cand, 2.0 * cand, math.inf):
            shield._model_order = list(order)
            res, used, _ = shield._verify(traj, ends, radius, hum, replan=(math.inf, c_min))
            stop = fixable and cand >= c_min
            stops.append(stop)
            assert used == (1 if stop else 3)
            np.testing.assert_array_equal(res.safe, lazy_safe if stop else full.safe)
            np.testing.assert_array_equal(res.threshold_J, lazy_thr if stop else full.threshold_J)
    assert any(stops) and not all(stops)  # both branches taken


def test_a_failed_lazy_first_check_rotates_the_first_checks_order() -> None:
    """A cycle whose first check fails on its first model and replans: the next cycle's first
    check starts with another model (a lazy check never completes, so it could not learn); the
    replans keep an order of their own."""
    from sara_app.bench.pfl import BENCH_CASES, shield_cell
    from sara_app.safety.pfl_shield import PflCycle

    shield, template, people, t = shield_cell(BENCH_CASES["slowed"])
    shield._orders[0][:] = ["acc", "vel", "pos", "combined"]
    out = shield.cycle(t, people, want_distance=False)
    info = shield._res
    assert isinstance(info, PflCycle) and info.checks == 2 and out.verified
    assert shield._orders[0] == ["vel", "pos", "combined", "acc"]
    assert shield._orders[1][0] in ("acc", "vel", "pos", "combined")
    assert shield._orders[0] is not shield._orders[1]


@pytest.mark.parametrize("path", ["reference", "compiled"])
@pytest.mark.parametrize("max_models", [1, 2, 4, 6])
def test_model_evaluations_per_cycle_stay_within_the_budget(max_models: int, path: str) -> None:
    """``SpeedScaling.max_models`` bounds the classifications of a cycle over all its checks
    (the braking bench state needs 6 without it); a cycle that runs out brakes on the held
    failsafe: it never commits a step that its checks did not prove. The reference is counted
    per check; the compiled cycle reports its count (``PflCycle.evaluations``)."""
    from sara_app.bench.pfl import BENCH_CASES, shield_cell
    from sara_app.safety.pfl_shield import PflCycle, SpeedScaling

    shield, template, people, t = shield_cell(BENCH_CASES["braking"])
    shield.scaling = SpeedScaling(max_models=max_models)
    evaluated: dict[int, int] = {}  # per check: the models it evaluated
    if path == "reference":
        ref = as_reference(shield)
        add_models = ref._add_models

        def counted(*args, **kw):  # type: ignore[no-untyped-def]
            out = add_models(*args, **kw)
            evaluated[id(ref._open[0])] = out[1]  # type: ignore[index]
            return out

        ref._add_models = counted  # type: ignore[method-assign]
    used = []
    for _ in range(4):  # the same state each cycle, as in the benchmark (model order learns)
        shield.follower = template.copy()
        shield.cap, shield._calm = math.inf, 0
        evaluated.clear()
        out = shield.cycle(t, people, want_distance=False)
        info = shield._res
        assert isinstance(info, PflCycle) and info.result is not None
        if path != "compiled":
            assert info.evaluations == sum(evaluated.values())
        else:
            assert not evaluated  # one compiled call
        assert info.evaluations <= max_models
        assert out.verified == info.result.safe_all
        assert out.mode == ("intended" if out.verified else "failsafe")
        used.append(info.evaluations)
    assert max(used) == min(max_models, 6)  # the budget binds, and 6 is what the state needs


def test_speed_scaling_is_validated() -> None:
    from sara_app.safety.pfl_shield import SpeedScaling

    with pytest.raises(ParameterError, match="max_models = 0"):
        SpeedScaling(max_models=0)
    with pytest.raises(ParameterError, match="max_replans = -1"):
        SpeedScaling(max_replans=-1)
    with pytest.raises(ParameterError, match="max_person_models = 0"):
        SpeedScaling(max_person_models=0)
    budget = SpeedScaling(max_models=6, max_person_models=16).model_budget
    assert [budget(h) for h in (0, 1, 2, 3, 4, 8, 16, 17, 100)] == [6, 6, 6, 5, 4, 2, 1, 1, 1]


@pytest.mark.parametrize("path", ["reference", "compiled"])
def test_with_four_people_a_cycle_evaluates_at_most_four_models(path: str) -> None:
    """The braking bench state with 4 people (the first one where the braking case puts them,
    three behind the robot whose sets reach it): the default budget lets a cycle evaluate 16 //
    4 = 4 models (6 for one person: the state needs 6), and a cycle that runs out brakes."""
    from sara_app.bench.people import others
    from sara_app.bench.pfl import BENCH_CASES, bench_cell
    from sara_app.safety.pfl_shield import PflCycle

    shield, template, people, t = bench_cell("pfl", [BENCH_CASES["braking"], *others(3)])
    if path == "reference":
        shield = as_reference(shield)
    for _ in range(3):
        shield.follower = template.copy()
        shield.cap, shield._calm = math.inf, 0
        out = shield.cycle(t, people, want_distance=False)
        info = shield._res
        assert isinstance(info, PflCycle) and info.evaluations == 4
        assert not out.verified and out.mode == "failsafe"


def test_classification_is_monotone_in_the_human_sets() -> None:
    """Basis of the per-entry merge: a larger set never gives a less severe verdict."""
    shield = reference_shield()
    t = run_free(shield, 60)
    rng = np.random.default_rng(3)
    traj, ends, radius = shield._plan(math.inf)
    smp = shield.pfl.motion.evaluate(traj.q, traj.v)
    dt = np.diff(traj.times)
    eps = shield.pfl.eps_from_bounds(dt, traj.v_bound, traj.a_bound)
    K = len(dt)
    for _ in range(12):
        x, y = rng.uniform(0.55, 1.1), rng.uniform(-0.6, 0.6)
        hum = hum_arrays(shield, [person(x, y, t)], t)
        h_e, h_r = shield._human_sets("vel", hum, traj.times, 0, K)
        args = (smp.ends, smp.p1_dot, smp.omega, dt)
        small = shield.pfl.check(
            ends, radius, *args, h_e, h_r, *shield.boxes, smp.energy_J, eps_v=eps
        )
        grown = h_r + rng.uniform(0.0, 0.3, h_r.shape)
        big = shield.pfl.check(
            ends, radius, *args, h_e, grown, *shield.boxes, smp.energy_J, eps_v=eps
        )
        c_s, c_b = small.contact, big.contact
        assert np.all(c_b.contact | ~c_s.contact)
        clamp_s, clamp_b = small.cls >= 2, big.cls >= 2
        assert np.all(clamp_b | ~clamp_s)
        touched = c_s.contact
        assert np.all(big.threshold_J[touched] <= small.threshold_J[touched])
        assert np.all(small.safe | ~big.safe)


@pytest.mark.parametrize("model", ["pos", "vel", "acc", "iso13855", "arm", "combined"])
def test_every_body_part_lies_in_its_capsule(model: str) -> None:
    shield = make_shield()
    reach = shield.reach
    pm = part_capsules(reach, model)
    rng = np.random.default_rng(1)
    sk, half = reach.skeleton, reach.params.half_thickness_m
    for trial in range(4):
        y = joints(standing((rng.uniform(-1, 1), rng.uniform(-1, 1)), rng.uniform(-3, 3)))
        y = y + rng.normal(0, 0.02, y.shape)
        occ = reach.model(model, y, np.zeros_like(y), np.full(len(y), 0.05), [0.0], [0.01])
        ends, rad = occ.ends[0, 0], occ.radius[0, 0]
        for p, (a, b) in enumerate(sk.part_joints):
            # points of the body part capsule: on the axis plus a random offset of its radius
            u = rng.uniform(0, 1, (200, 1))
            d = rng.normal(size=(200, 3))
            d *= (half[p] * rng.uniform(0, 1, (200, 1)) ** (1 / 3)) / np.linalg.norm(
                d, axis=1, keepdims=True
            )
            pts = y[a] + u * (y[b] - y[a]) + d
            inside = points_in_capsules(pts, ends[pm[p] : pm[p] + 1], rad[pm[p] : pm[p] + 1])
            assert inside.all(), (model, sk.parts[p], trial)


def _check_commit_or_brake(shield: PflShield, t: float, people: list[HumanState]) -> object:
    before = shield.follower.copy()
    out = shield.cycle(t, people)
    if out.verified:
        assert out.mode in ("intended", "rest", "failsafe")
        assert out.pfl is None or out.pfl.safe_all
        traj = out.trajectory
        at_end = JointState(traj.q[1], traj.v[1], traj.a[1])  # the shield's own sample
        np.testing.assert_array_equal(out.command.q, before.copy().commit(traj.step, at_end).q)
        on_path = before.copy().commit(traj.step).q  # and that sample is the step's end
        np.testing.assert_allclose(out.command.q, on_path, rtol=0.0, atol=1e-12)
    else:
        # not verified: exactly the held failsafe
        np.testing.assert_array_equal(out.command.q, before.brake(shield.settings.dt_s).q)
        np.testing.assert_array_equal(out.command.v, shield.follower.state.v)
    assert shield.follower.speed_cap == math.inf  # the cap never leaks into the follower
    return out


def test_commits_only_verified_steps_and_slows_near_a_person() -> None:
    shield = make_shield()
    t = run_free(shield, 60)
    sd_free = shield.follower.sd
    assert sd_free > 1.0
    scaled, moving_scaled, unverified = 0, 0, 0
    dt = shield.settings.dt_s
    for _ in range(300):
        out = _check_commit_or_brake(shield, t, [person(0.85, 0.0, t - 0.01)])
        t += dt
        unverified += not out.verified
        if out.speed_scale < 1.0:
            scaled += 1
            assert out.intervened
            moving_scaled += out.verified and shield.follower.sd > 0.0
        if shield.task_done:
            break
    assert scaled > 0 and moving_scaled > 0  # it slowed down and kept moving while slowed
    assert shield.replans > 0


def test_nobody_means_full_speed() -> None:
    shield = make_shield()
    for k in range(40):
        out = shield.cycle(k * shield.settings.dt_s, [])
        assert out.verified and out.speed_scale == 1.0 and not out.intervened
        assert out.pfl is None
    assert shield.cap == math.inf and shield.follower.sd > 0.5


def test_robot_at_rest_verifies_with_a_person_touching_it() -> None:
    shield = make_shield()
    # a person standing on the robot base: every contact possible, but no energy
    out = shield.cycle(0.0, [person(0.0, 0.0, 0.0)])
    assert out.verified and out.pfl is not None and (out.pfl.cls > 0).any()


@pytest.mark.parametrize(
    "bad",
    [
        lambda h: HumanState(h.id, h.y * np.nan, h.v, h.dv, h.stamp_s),
        lambda h: HumanState(h.id, h.y[:5], h.v, h.dv, h.stamp_s),
        lambda h: HumanState(h.id, h.y, h.v, -h.dv, h.stamp_s),
        lambda h: HumanState(h.id, h.y, h.v, h.dv, None),
        lambda h: HumanState(h.id, h.y, h.v, h.dv, -10.0),
    ],
)
def test_faults_brake_on_the_held_failsafe(bad) -> None:  # type: ignore[no-untyped-def]
    shield = make_shield()
    t = run_free(shield, 60)
    before = shield.follower.copy()
    out = shield.cycle(t, [bad(person(1.5, 0.0, t))])
    assert out.mode == "fault" and not out.verified
    np.testing.assert_array_equal(out.command.q, before.brake(shield.settings.dt_s).q)


@pytest.mark.parametrize("where", ["validated", "run"])
def test_numeric_failure_inside_the_check_is_a_fault(
    monkeypatch: pytest.MonkeyPatch, where: str
) -> None:
    """A numeric failure while the check's inputs are prepared, or in the compiled cycle, is a
    fault of the cycle."""
    shield = make_shield()
    t = run_free(shield, 30)

    def boom(*a: object, **k: object) -> None:
        raise ValueError("broken")

    monkeypatch.setattr(shield.compiled, where, boom)
    out = shield.cycle(t, [person(0.6, 0.0, t)])
    assert out.mode == "fault" and any("PFL check failed" in f for f in out.faults)


def test_a_distant_second_person_changes_no_verdict() -> None:
    shield = reference_shield()
    t = run_free(shield, 60)
    one = [person(0.85, 0.0, t)]
    two = one + [person(-3.0, 3.0, t, "far")]
    traj, ends, radius = shield._plan(math.inf)
    r1 = shield._verify(traj, ends, radius, hum_arrays(shield, one, t))[0]
    traj, ends, radius = shield._plan(math.inf)
    r2 = shield._verify(traj, ends, radius, hum_arrays(shield, two, t))[0]
    P = len(shield._part_names)
    np.testing.assert_array_equal(r2.safe[:, :, :P], r1.safe)
    assert r2.safe[:, :, P:].all()
    assert 2 in shield._checks


def test_threshold_edits_and_boxes_are_validated() -> None:
    edit = {"region": "hand", "contact": "constrained", "shape": "blunt", "energy_J": 0.5}
    shield = make_shield(overrides=[edit])
    assert shield.thresholds.energy_J("hand", "constrained", "blunt") == 0.5
    assert shield.above_source  # above the paper's 0.12 J: flagged
    with pytest.raises(ParameterError, match="boxes"):
        PflShield(
            shield.robot, shield.follower, shield.reach, shield.settings, shield.spec,
            (np.eye(4)[None], np.array([[0.1, -0.1, 0.1]])),
        )  # fmt: skip


def test_interval_energy_bound_covers_dense_samples() -> None:
    """The energy per interval passed to the check covers the link energies densely sampled
    inside every interval (the speed peaks inside the first failsafe interval, where the end
    samples of Thumm et al. 2024 eq. 47-48 alone miss it)."""
    from sara_app.robot.trajectory import PathFollower

    shield = make_shield()
    lim = shield.robot.limits
    rng = np.random.default_rng(11)
    missed_by_ends = 0.0
    for _ in range(25):
        lo = lim.q_min + 0.25 * (lim.q_max - lim.q_min)
        hi = lim.q_max - 0.25 * (lim.q_max - lim.q_min)
        f = PathFollower(rng.uniform(lo, hi, (3, 7)), shield.follower.limits)
        for _ in range(int(rng.integers(5, 150))):
            if rng.uniform() < 0.1:
                f.speed_cap = rng.uniform(0.05, 2.5)
            f.step(shield.settings.dt_s)
        shield.follower = f
        traj, _, _ = shield._plan(math.inf)
        E_s = shield.pfl.motion.evaluate(traj.q, traj.v).energy_J.copy()
        bound = shield._link_energies(traj)[1]
        # _link_energies takes the path tangent as v / s' where the robot moves: v = q' s'
        tangent = traj.step.path.derivatives(traj.s, 1)[1]
        moving = traj.sd > 1e-6
        np.testing.assert_allclose(
            traj.v[moving] / traj.sd[moving, None], tangent[moving], rtol=1e-12, atol=1e-12
        )
        prof = traj.step.profile.then(traj.stop.profile)
        for k in range(len(traj.times) - 1):
            s, sd, _ = prof.evaluate(np.linspace(traj.times[k], traj.times[k + 1], 40))
            q, dq = traj.step.path.derivatives(s, 1)
            dense = shield.pfl.motion.energies(q, dq * sd[:, None]).max(axis=0)
            assert np.all(dense <= bound[k] + 1e-12), (k, dense / bound[k])
            ends = np.maximum(E_s[k], E_s[k + 1])
            missed_by_ends = max(missed_by_ends, float(np.max(dense - ends)))
    assert missed_by_ends > 0.0  # the end samples alone would have missed energy


def _ref_speed_for(res, sd: np.ndarray, which: np.ndarray) -> float:  # type: ignore[no-untyped-def]
    """The numpy formula the compiled candidate search replaced."""
    if not which.any():
        return math.inf
    k, i, j = np.nonzero(which)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = res.threshold_J[k, i, j] / res.energy_J[k, i]
        c = np.maximum(np.abs(sd[:-1]), np.abs(sd[1:]))[k] * np.sqrt(ratio)
    return float(np.where(np.isnan(c), 0.0, c).min())


def test_compiled_speed_candidates_equal_the_numpy_formula() -> None:
    from types import SimpleNamespace

    rng = np.random.default_rng(8)
    for trial in range(60):
        K, L, P = int(rng.integers(1, 6)), int(rng.integers(1, 5)), int(rng.integers(1, 6))
        cls = rng.integers(0, 4, (K, L, P)).astype(np.int8) * (rng.random((K, L, P)) < 0.5)
        thr = rng.choice([0.12, 0.49, 1.3, 2.0], (K, L, P))
        E = rng.uniform(0.0, 2.5, (K, L)) * (rng.random((K, L)) < 0.9)
        if trial % 7 == 0:
            E[0, 0] = np.nan
        safe = (cls == 0) | (thr > E[:, :, None])
        res = SimpleNamespace(safe=safe, cls=cls, threshold_J=thr, energy_J=E)
        sd = np.abs(rng.normal(size=K + 1)) * (rng.random(K + 1) < 0.8)
        traj = SimpleNamespace(sd=sd)
        E0 = rng.uniform(0, 1, L)
        cand, fixable = candidate(res, traj, E0)  # type: ignore[arg-type]
        assert cand == _ref_speed_for(res, sd, ~safe)
        assert fixable == (not (~safe[0] & ~(E0[:, None] < thr[0])).any())
        assert allowed_speed(res, traj) == _ref_speed_for(res, sd, cls > 0)  # type: ignore[arg-type]


@pytest.mark.parametrize("case", ["clear", "slowed", "braking"])
def test_a_cycle_leaves_no_reference_cycles(case: str) -> None:
    """Everything a PFL cycle allocates is freed by reference counting: garbage that only the
    cyclic collector frees means collector pauses in the control loop (a deferred check's link
    state closure once kept ~35 objects per cycle alive this way)."""
    import gc

    from sara_app.bench.pfl import BENCH_CASES, shield_cell

    shield, template, people, t = shield_cell(BENCH_CASES[case])
    for _ in range(3):  # warm: first-use allocations
        shield.follower = template.copy()
        shield.cycle(t, people, want_distance=False)
    gc.collect()
    gc.set_debug(gc.DEBUG_SAVEALL)
    try:
        for _ in range(5):
            shield.follower = template.copy()
            shield.cap = math.inf
            shield.cycle(t, people, want_distance=False)
        gc.collect()
        garbage = [type(o).__qualname__ for o in gc.garbage]
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
    assert garbage == []
