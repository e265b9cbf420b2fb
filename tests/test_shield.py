"""The SSM shield (``sara_app.safety.shield``): faults brake along the held failsafe and never
raise, an unverified cycle never commits the intended step, the robot at rest stays verified,
and, in closed loop, every executed motion lies inside the occupancy of a verified shielded
trajectory (the induction the guarantee rests on)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sara_app.geometry.shapes import point_segment_distance
from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.scripted import joints, standing
from sara_app.robot.model import load_robot
from sara_app.robot.trajectory import JointState, PathFollower
from sara_app.safety.settings import FUTURE_TOLERANCE_S, ShieldSettings
from sara_app.safety.shield import CycleResult, HumanState, Shield
from sara_app.scenario import parse_scenario
from sara_app.sim.simulator import Simulation

ROBOT = load_robot("panda")
PARAMS = to_reach_params(load_param_set("schepp2022_table1"), "full")
REACH = HumanReach(PARAMS)
WPS = np.array([[-1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8], [1.2, 0.3, 0.0, -1.8, 0.0, 2.1, 0.8]])
DT = ShieldSettings().dt_s
TOL = ShieldSettings().tracking_tol_rad
FAULTS = ("nan", "inf_v", "stale", "future", "shape", "missing", "bad_dv", "jump", "q_nan")
SETTINGS = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def make_shield(wps: np.ndarray = WPS) -> Shield:
    return Shield(ROBOT, PathFollower(wps, ROBOT.limits), REACH, ShieldSettings())


def person(xy: tuple[float, float], t_stamp: float | None, hid: str = "p") -> HumanState:
    y = joints(standing(xy, math.atan2(-xy[1], -xy[0])))
    return HumanState(hid, y, np.zeros_like(y), np.full(len(y), 0.05), t_stamp)


def path_state(sh: Shield) -> np.ndarray:
    f = sh.follower
    return np.array([f.s, f.sd, f.sdd])


def good_inputs(
    sh: Shield, t: float, rng: np.random.Generator, far: tuple[float, float] = (3.0, 0.5)
) -> tuple[list[HumanState], JointState]:
    """A person far away measured 10 ms ago; a measured robot state within tracking tolerance."""
    st_ = sh.follower.state
    q = st_.q + rng.uniform(-0.9, 0.9, st_.q.shape) * TOL
    return [person(far, t - 0.01)], JointState(q, st_.v, st_.a)


def bad_inputs(
    sh: Shield, t: float, kind: str, u: float, rng: np.random.Generator
) -> tuple[list[HumanState], JointState]:
    humans, measured = good_inputs(sh, t, rng)
    h = humans[0]
    j = int(rng.integers(15))
    if kind == "nan":
        h.y = h.y.copy()
        h.y[j, int(rng.integers(3))] = np.nan
    elif kind == "inf_v":
        h.v = h.v.copy()
        h.v[j, 0] = np.inf
    elif kind == "stale":
        h.stamp_s = t - ShieldSettings().skeleton_timeout_s - 0.001 - u
    elif kind == "future":
        h.stamp_s = t + FUTURE_TOLERANCE_S + 0.001 + u
    elif kind == "shape":
        h.y = h.y[:14]
    elif kind == "missing":
        h.stamp_s = None
    elif kind == "bad_dv":
        h.dv = h.dv.copy()
        h.dv[j] = np.nan if u < 0.5 else -1.0
    elif kind == "jump":
        q = sh.follower.state.q.copy()
        q[int(rng.integers(len(q)))] += (1.0 if u < 0.5 else -1.0) * TOL * (1.05 + 10 * u)
        measured = JointState(q, measured.v, measured.a)
    elif kind == "q_nan":
        q = measured.q.copy()
        q[0] = np.nan
        measured = JointState(q, measured.v, measured.a)
    return humans, measured


def check_braked(sh: Shield, before: np.ndarray, held_end: float, held: object) -> None:
    """The cycle advanced exactly ``dt`` along the failsafe held before it."""
    s, sd, sdd = (float(x[0]) for x in held.path_samples([DT]))  # type: ignore[attr-defined]
    np.testing.assert_allclose(path_state(sh), [s, sd, sdd], rtol=0, atol=1e-9)
    assert sh.follower.stop.s_end == held_end or math.isclose(
        sh.follower.stop.s_end, held_end, abs_tol=1e-9
    )
    assert sh.follower.s <= held_end + 1e-9
    assert sh.follower.s >= before[0] - 1e-12  # never backwards


@SETTINGS
@given(
    st.sampled_from(FAULTS),
    st.integers(5, 120),
    st.integers(1, 80),
    st.floats(0.0, 1.0),
    st.integers(0, 2**31),
)
def test_faults_brake_on_held_failsafe_then_recover(
    kind: str, n_pre: int, n_fault: int, u: float, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    sh = make_shield()
    t = 0.0
    for _ in range(n_pre):
        res = sh.cycle(t, *good_inputs(sh, t, rng))
        assert res.mode == "intended" and res.verified and not res.faults
        t += DT
    held_end = sh.follower.stop.s_end
    stop_cycles = math.ceil(sh.follower.stop.duration_s / DT)
    for k in range(n_fault):
        before, held = path_state(sh), sh.follower.stop
        res = sh.cycle(t, *bad_inputs(sh, t, kind, u, rng))
        assert res.mode == "fault" and not res.verified and res.faults, res
        check_braked(sh, before, held_end, held)
        if k >= stop_cycles:
            assert sh.follower.sd <= 1e-9  # the held stop has ended: at rest
        t += DT
    res = sh.cycle(t, *good_inputs(sh, t, rng))
    assert res.mode == "intended" and res.verified and not res.faults


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.floats(0.3, 2.0), st.floats(-np.pi, np.pi), st.integers(0, 2**31), st.integers(0, 3))
def test_unverified_cycles_never_commit_the_intended_step(
    dist: float, ang: float, seed: int, stale_every: int
) -> None:
    """A person standing anywhere around the robot; every cycle either verifies (and executes
    exactly the checked step) or brakes exactly along the held failsafe."""
    rng = np.random.default_rng(seed)
    sh = make_shield()
    xy = (dist * math.cos(ang), dist * math.sin(ang))
    t = 0.0
    for k in range(150):
        stamp = t - 0.01 if not stale_every or k % (5 * stale_every) else t - 1.0
        before, held = path_state(sh), sh.follower.stop
        q = sh.follower.state.q + rng.uniform(-0.9, 0.9, 7) * TOL
        res = sh.cycle(t, [person(xy, stamp)], JointState(q, q * 0, q * 0))
        if res.verified:
            assert res.trajectory is not None and res.ssm is not None and res.ssm.safe
            np.testing.assert_allclose(path_state(sh), res.trajectory.step.end, atol=1e-12)
            assert res.mode in ("intended", "failsafe", "rest")
        else:
            assert res.mode in ("failsafe", "fault", "rest")
            check_braked(sh, before, held.s_end, held)
        t += DT


def test_at_rest_without_humans_stays_verified() -> None:
    wps = np.array([WPS[0], WPS[0] + 0.05])
    sh = make_shield(wps)
    t = 0.0
    for _ in range(400):
        res = sh.cycle(t, [], sh.follower.state)
        assert res.verified and res.mode in ("intended", "rest")
        t += DT
        if sh.follower.done:
            break
    assert sh.follower.done
    q = sh.follower.state.q.copy()
    for _ in range(50):
        res = sh.cycle(t, [], sh.follower.state)
        assert res.verified and res.mode == "rest" and not res.faults
        np.testing.assert_array_equal(res.command.q, q)
        t += DT


def test_person_touching_robot_at_rest_keeps_it_still() -> None:
    """A person overlapping the resting robot: never verified, the robot does not move, no
    exception; once the person leaves, the robot starts."""
    sh = make_shield()
    q0 = sh.follower.state.q.copy()
    t = 0.0
    for _ in range(50):
        res = sh.cycle(t, [person((0.2, 0.0), t - 0.01)], sh.follower.state)
        assert not res.verified and res.mode == "failsafe"
        np.testing.assert_array_equal(res.command.q, q0)
        assert res.min_distance_m is not None and res.min_distance_m < 0.0
        t += DT
    res = sh.cycle(t, [person((3.0, 0.0), t - 0.01)], sh.follower.state)
    assert res.verified and res.mode == "intended"


def test_tracking_error_just_inside_tolerance_is_no_fault() -> None:
    sh = make_shield()
    rng = np.random.default_rng(1)
    t = 0.0
    for _ in range(60):
        q = sh.follower.state.q + rng.choice([-1.0, 1.0], 7) * TOL * (1 - 1e-6)
        res = sh.cycle(t, [person((3.0, 0.0), t - 0.01)], JointState(q, q * 0, q * 0))
        assert not res.faults and res.mode == "intended"
        t += DT


# ----------------------------------------------------------------------------------------------
# Induction in closed loop


def _contained(ends: np.ndarray, rad: np.ndarray, box_ends: np.ndarray, box_rad: np.ndarray):
    """Capsules ``(L, 2, 3), (L,)`` inside capsules ``(L, 2, 3), (L,)`` link by link: both end
    balls inside (a capsule is the convex hull of its end balls; a capsule is convex)."""
    d = point_segment_distance(ends, box_ends[:, None])  # (L, 2)
    return d.max(axis=1) + rad <= box_rad + 1e-9


def _episode(strategy: str, seed: int, xy: tuple[float, float]) -> Simulation:
    sc = parse_scenario(
        {
            "name": "induction",
            "task": {"waypoints_rad": WPS.tolist(), "cycles": 4},
            "humans": [
                {
                    "id": "adv",
                    "type": "adversarial",
                    "strategy": strategy,
                    "position_m": list(xy),
                    "seed": seed,
                }
            ],
            "shield": {"models": ["acc", "vel", "pos"] if strategy == "rigid" else ["acc", "vel"]},
        }
    )
    return Simulation(sc)


@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.sampled_from(["rigid", "limbs"]),
    st.integers(0, 2**20),
    st.floats(1.0, 1.5),
    st.floats(-np.pi, np.pi),
)
def test_executed_motion_inside_verified_occupancy(
    strategy: str, seed: int, dist: float, ang: float
) -> None:
    """Every executed step, sampled densely, has every link capsule inside that link's capsule
    for the covering interval of the last verified shielded trajectory (at rest after its end);
    the tracking margin is removed first, so the check does not lean on it."""
    sim = _episode(strategy, seed, (dist * math.cos(ang), dist * math.sin(ang)))
    sh = sim.shield
    verified: tuple[float, CycleResult] | None = None
    taus = np.linspace(0.0, DT, 5)
    modes = set()
    for _ in range(300):
        f = sh.follower
        t0, held, start = sim.t, f.stop, (f.s, f.sd, f.sdd)
        path = f.path
        sim.step()
        res = sim.last
        assert res is not None
        modes.add(res.mode)
        if res.verified:
            verified = (t0, res)
            prof = res.trajectory.step.profile  # type: ignore[union-attr]
            s = prof.evaluate(taus)[0]
        else:
            assert held.profile.start == start
            s = held.path_samples(taus)[0]
        if verified is None:  # nothing verified yet (no skeleton): the robot has not moved
            assert sh.follower.s == 0.0 and sh.follower.sd == 0.0
            continue
        tv, rv = verified
        assert rv.trajectory is not None and rv.robot_ends is not None
        assert rv.robot_radius is not None
        times = tv + rv.trajectory.times
        qs = path.q(s)
        for tau, q in zip(taus, qs):
            t_abs = t0 + tau
            k = int(np.searchsorted(times, t_abs - 1e-12, side="left")) - 1
            k = max(k, 0)
            ends, rad = ROBOT.link_capsules(q)
            if k >= len(times) - 1:  # after the end of the verified stop: at rest there
                np.testing.assert_allclose(q, rv.trajectory.q[-1], atol=1e-9)
                k = len(times) - 2
            box_r = rv.robot_radius[k] - sh.tracking_margin_m
            assert np.all(_contained(ends, rad, rv.robot_ends[k], box_r)), (t_abs, k)
    assert "failsafe" in modes and "intended" in modes


def test_model_flags_are_the_checks_per_model() -> None:
    """Each cycle's per-model verdicts (``model_free``, the verdict message's ``results``): a
    model is listed when it was evaluated for every person and interval, free when its sets
    were free on all of them, by the arrays of the check the cycle ran (compiled or composed,
    the model order as the check tried it)."""
    sim = _episode("limbs", 3, (1.1, 0.2))
    seen: set[tuple[str, bool]] = set()
    for _ in range(300):
        sim.step()
        res = sim.last
        assert res is not None
        if res.ssm is None:
            assert res.model_free == {}
            continue
        r = res.ssm
        models = r.models or sim.shield.verifier.models
        want = {
            m: bool(r.free[:, i].all()) for i, m in enumerate(models) if r.evaluated[:, i].all()
        }
        assert res.model_free == want
        seen |= set(want.items())
    assert {flag for _, flag in seen} == {True, False}  # both verdicts occurred


def test_min_distance_is_the_distance_at_the_command() -> None:
    """The verdict's minimum distance (one compiled call) equals pinocchio's link capsules and
    ``body_distance`` at the commanded configuration, for verified and braking cycles alike."""
    from sara_app.safety.ssm import body_distance

    sh = make_shield()
    parts, half = sh.reach.skeleton.part_joints, REACH.params.half_thickness_m
    t, modes = 0.0, set()
    for i in range(250):
        xy = (1.5 - 0.008 * i, 0.3)  # walks in: verified, then slowed, then braking cycles
        h = person(xy, t - 0.01)
        res = sh.cycle(t, [h], sh.follower.state)
        ends, rad = ROBOT.link_capsules(res.command.q)
        want = body_distance(h.y, parts, half, ends, rad)
        assert res.min_distance_m is not None
        assert abs(res.min_distance_m - want) <= 1e-12
        modes.add(res.mode)
        t += DT
    assert {"intended", "failsafe"} <= modes


def test_a_restart_from_a_measured_rest_keeps_to_the_paths_corners() -> None:
    """A robot at rest halfway along the first leg of an L-shaped path (a re-anchor, an
    operator's re-plan, a robot edit): the new plan goes through the corner, where it went
    straight to the path's end across what the corner goes around."""
    corner = WPS[0] + [1.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    end = corner + [0.0, 0.0, 0.0, 0.6, 0.0, 0.0, 0.0]
    path = np.array([WPS[0], corner, end])
    shield = Shield(ROBOT, PathFollower(path, ROBOT.limits), REACH, ShieldSettings())
    halfway = (WPS[0] + corner) / 2
    shield.restart_from(halfway)
    np.testing.assert_allclose(shield.follower.path.waypoints, [halfway, corner, end])
    shield.restart_from(end)  # at the end: it rests there
    np.testing.assert_allclose(shield.follower.path.waypoints, [end])
    assert shield.at_rest and shield.follower.done
