"""Speed cap of the path follower (PFL speed scaling): the intended motion slows to the cap within
the joint limits, stays below it, and resumes when the cap is raised; the failsafe stays valid
(no fallback step: every intended step passed the limit check and has a stop from its end).

Limits are checked on densely sampled positions with the finite-difference helper of the
trajectory tests (``panda_limits.check_limits``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from panda_limits import DT, HOME, PANDA, H, check_limits  # noqa: E402

from sara_app.errors import RobotModelError
from sara_app.robot.trajectory import PathFollower

LONG = np.array([HOME, HOME + [2.0, 0.5, 0, 0.6, 0, 0, 0.8], HOME + [2.4, -0.6, 0.8, 0, 0, 0, 0]])


def _segments(f: PathFollower, plan: list[tuple[float, float]]) -> list[tuple[np.ndarray, ...]]:
    """Run ``f`` with ``(cap, until_t)`` stages; dense samples ``(t, s, sd)`` per stage."""
    out = []
    for cap, until in plan:
        f.speed_cap = cap
        t, s, sd, _ = f.rollout(DT, until, sample_dt=H)
        out.append((t, s, sd))
    return out


def _all_positions(f: PathFollower, segs: list[tuple[np.ndarray, ...]]) -> np.ndarray:
    # each stage ends with the state the next one starts from: drop the duplicate sample
    s = np.concatenate([seg[1][:-1] for seg in segs[:-1]] + [segs[-1][1]])
    return np.asarray(f.path.q(s))


def test_cap_slows_to_the_cap_within_limits_and_raising_resumes() -> None:
    f = PathFollower(LONG, PANDA)
    cap = 0.3
    segs = _segments(f, [(math.inf, 0.6), (cap, 2.0), (math.inf, 30.0)])
    t1, _, sd1 = segs[0]
    assert sd1.max() > 2 * cap  # it was going faster than the cap
    t2, s2, sd2 = segs[1]
    # decelerating at least at the path's smallest acceleration box, plus jerk ramps
    settle = t2[0] + (sd1[-1] - cap) / f._A_min + 2 * f._A_top / f._J_min + 2 * DT
    late = t2 >= settle
    assert late.sum() > 100
    assert np.all(sd2[late] <= cap * (1 + 1e-9) + 1e-12)
    assert sd2[-1] > 0.9 * cap  # still moving at the cap (not stopped)
    assert np.all(np.diff(s2) >= -1e-12) and np.all(sd2 >= -1e-12)
    # raising the cap resumes full speed and reaches the goal
    _, _, sd3 = segs[2]
    assert f.done and sd3.max() > 2 * cap
    assert f.fallback_steps == 0
    check_limits(_all_positions(f, segs))
    np.testing.assert_allclose(f.state.q, LONG[-1], atol=1e-9)


def test_cap_zero_rests_on_the_path_and_resumes() -> None:
    f = PathFollower(LONG, PANDA)
    segs = _segments(f, [(math.inf, 0.5), (0.0, 1.5)])
    assert f.sd == 0.0 and abs(f.sdd) <= 1e-7 and not f.done
    s_rest = f.s
    for _ in range(20):  # stays put
        f.step(DT)
    assert f.s == s_rest
    segs.append(_segments(f, [(math.inf, 30.0)])[0])
    assert f.done and f.fallback_steps == 0
    check_limits(_all_positions(f, segs))


def test_infinite_cap_is_the_uncapped_motion() -> None:
    a, b = PathFollower(LONG, PANDA), PathFollower(LONG, PANDA)
    b.speed_cap = math.inf
    ra, rb = a.rollout(DT, 30.0), b.rollout(DT, 30.0)
    for x, y in zip(ra, rb, strict=True):
        np.testing.assert_array_equal(x, y)


def test_cap_above_the_admissible_speed_changes_nothing() -> None:
    a, b = PathFollower(LONG, PANDA), PathFollower(LONG, PANDA)
    b.speed_cap = 1.01 * float(np.max(a.admissible_speed[1]))
    np.testing.assert_array_equal(a.rollout(DT, 30.0)[1], b.rollout(DT, 30.0)[1])


@pytest.mark.parametrize("bad", [-0.1, math.nan, "fast", None, -math.inf])
def test_bad_cap_is_refused(bad: object) -> None:
    f = PathFollower(LONG, PANDA)
    with pytest.raises(RobotModelError, match="speed_cap"):
        f.speed_cap = bad  # type: ignore[assignment]
    assert f.speed_cap == math.inf


waypoints = (
    st.integers(0, 2**32 - 1)
    .map(lambda seed: np.random.default_rng(seed).uniform(0.1, 0.9, (int(seed % 3) + 2, 7)))
    .map(lambda u: PANDA.q_min + (PANDA.q_max - PANDA.q_min) * (0.5 + 0.6 * (u - 0.5)))
)


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    waypoints,
    st.floats(0.05, 0.4),
    st.floats(0.05, 0.9),
    st.sampled_from([0.03, 0.1, 0.3]),
)
def test_random_caps_keep_limits_and_converge(
    wps: np.ndarray, t_cap: float, frac: float, bd: float
) -> None:
    """Caps switched at random times, on random paths (blends included): joint limits hold,
    the speed settles below each cap, and the goal is reached once the cap is lifted."""
    f = PathFollower(wps, PANDA, blend_distance=bd)
    cap = frac * float(np.max(f.admissible_speed[1]))
    segs = _segments(f, [(math.inf, t_cap), (cap, t_cap + 1.0), (0.5 * cap, t_cap + 2.0)])
    for (t, _, sd), c in zip(segs[1:], (cap, 0.5 * cap), strict=True):
        if f.done or t.size < 2:
            break
        settle = t[0] + max(sd[0] - c, 0.0) / f._A_min + 2 * f._A_top / f._J_min + 2 * DT
        late = t >= settle
        assert np.all(sd[late] <= c * (1 + 1e-9) + 1e-12)
    segs.append(_segments(f, [(math.inf, 60.0)])[0])
    assert f.done and f.fallback_steps == 0
    check_limits(_all_positions(f, segs))
