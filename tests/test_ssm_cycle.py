"""The SSM cycle's compiled call (sara_app.safety.ssm_cycle_kernels) against the Python composition
of the same kernels (``Shield._composed``): from the same follower state and people, the same
shielded trajectory, robot capsules, per-part verdicts and speed scale, bit for bit, over a
closed loop whose people come and go near the robot's path (checks that verify at once, replans,
and cycles that brake), and the same model put first for the next check; the arm model keeps
the Python composition."""

from __future__ import annotations

import math

import numpy as np

from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.scripted import joints, standing
from sara_app.robot.model import load_robot
from sara_app.robot.trajectory import PathFollower
from sara_app.safety.settings import ShieldSettings
from sara_app.safety.shield import HumanState, Shield

ROBOT = load_robot("panda")
WPS = np.array([[-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8], [1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8]])
TRAJ_FIELDS = ("times", "q", "v", "a", "s", "sd", "sdd", "v_bound", "a_bound", "dq", "sd_max")


def _shield(models: tuple[str, ...] = ("pos", "vel", "acc")) -> Shield:
    reach = HumanReach(to_reach_params(load_param_set("bench_work"), "full"))
    settings = ShieldSettings(models=models)
    return Shield(ROBOT, PathFollower(WPS, ROBOT.limits), reach, settings)


def _people(rng: np.random.Generator, t: float, n: int) -> list[HumanState]:
    out = []
    for i in range(n):
        r, a = rng.uniform(0.35, 1.8), rng.uniform(-math.pi, math.pi)
        xy = (r * math.cos(a), r * math.sin(a))
        y = joints(standing(xy, math.atan2(-xy[1], -xy[0])))
        v = rng.normal(0.0, 0.3, y.shape)
        dv = np.full(len(y), rng.uniform(0.01, 0.2))
        out.append(HumanState(f"p{i}", y, v, dv, t - rng.uniform(0.0, 0.03)))
    return out


def _same(a: object, b: object, what: str) -> None:
    np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=what)


def test_the_compiled_cycle_equals_the_python_composition() -> None:
    rng = np.random.default_rng(7)
    sh = _shield()
    dt = sh.settings.dt_s
    checks, verdicts = [], []
    firsts: set[str] = set()  # the models tried first
    composed = sh._composed
    fallbacks = []  # cycles where _plan_and_verify ran the Python composition

    def counted(hum):  # type: ignore[no-untyped-def]
        fallbacks.append(hum is None)
        return composed(hum)

    t = 0.0
    for cycle in range(400):
        if cycle % 40 == 0:
            n = int(rng.integers(0, 3))
        people = _people(rng, t, n) if n else []
        ages: dict[str, float] = {}
        usable = sh._check_humans(t, people, [], ages)
        hum = sh._human_arrays(people, usable, ages)
        start = sh.follower.copy()
        sh.follower, sh._res = start.copy(), None  # as Shield.cycle starts
        sh._composed = counted  # type: ignore[method-assign]
        order = sh.verifier.order
        got = sh._plan_and_verify(hum)
        sh._composed = composed  # type: ignore[method-assign]
        got_res, got_scale, info = sh._res, sh._scale, sh._info.copy()
        sh.follower, sh._res = start.copy(), None
        promoted, _ = sh.verifier.order, sh.verifier.set_order(order)
        want = sh._composed(hum)
        assert sh.verifier.order == promoted  # both paths put the same model first
        firsts.add(promoted[0])
        want_res, want_scale = sh._res, sh._scale
        for name in TRAJ_FIELDS:
            _same(getattr(got[0], name), getattr(want[0], name), name)
        for a, b in ((got[0].step.profile, want[0].step.profile),
                     (got[0].stop.profile, want[0].stop.profile)):  # fmt: skip
            assert (a.start, list(a.durs), list(a.jerks)) == (b.start, list(b.durs), list(b.jerks))
        assert got[0].step.end == want[0].step.end and got[0].step.fallback == want[0].step.fallback
        _same(got[1], want[1], "ends")
        _same(got[2], want[2], "radius")
        assert got[3] == want[3] and got_scale == want_scale
        assert type(got[3]) is type(want[3]) is bool and type(got_scale) is float  # a verdict's
        if hum is None:
            assert got_res is None and want_res is None
        else:
            for name in ("safe", "free", "evaluated", "closest_m", "parts_clear"):
                _same(getattr(got_res, name), getattr(want_res, name), name)
            checks.append(int(info[2]))
            verdicts.append(got[3])
        sh.follower = start
        sh.cycle(t, people, want_distance=False)
        t += dt
    assert all(fallbacks) and len(fallbacks) < 400  # only where nobody was in the cell
    assert max(checks) > 1 and 1 in checks  # replans and checks that verified at once
    assert any(verdicts) and not all(verdicts)  # cycles that moved and cycles that braked
    assert len(firsts) > 1  # the model that completed a check went first


def test_the_arm_model_keeps_the_python_composition() -> None:
    assert _shield(("arm", "pos"))._compiled is None
    assert _shield()._compiled is not None


def test_the_compiled_cycles_separation_is_min_distance_at_the_command() -> None:
    """Where the compiled call's plan is committed, the separation it reports (from its
    occupancy's capsule ends at sample 1) is ``Shield.min_distance`` at the command, bit for
    bit; where the cycle brakes or nobody is there, the cycle calls ``min_distance`` itself."""
    rng = np.random.default_rng(11)
    sh = _shield()
    t, used, braked = 0.0, 0, 0
    for cycle in range(400):
        if cycle % 40 == 0:
            n = int(rng.integers(0, 3))
        people = _people(rng, t, n) if n else []
        res = sh.cycle(t, people)
        if people:
            want = sh.min_distance(res.command.q, [p.y for p in people])
            assert res.min_distance_m is not None
            assert res.min_distance_m == want or (
                math.isnan(res.min_distance_m) and math.isnan(want)
            )
            used += sh._separation is not None and res.verified
            braked += not res.verified
        else:
            assert res.min_distance_m is None
        t += sh.settings.dt_s
    assert used > 50 and braked > 10  # both kinds of cycle
