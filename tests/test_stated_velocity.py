"""A tracker's stated velocities against the positions (``sara_app/human/stated_velocity.py``):
the ball used encloses every velocity both claims allow (brute force over sampled lenses), a
contradiction is found exactly where the balls do not meet, honest velocities are never
refused, and reversed ones (a frame transformation applied to positions only) fault the person
through the path the worker takes (``ingest_skeleton``)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from stated_velocity_reference import reconcile as reconcile_reference

from sara_app.bus.messages import SkeletonMsg
from sara_app.cell.build import build_cell
from sara_app.cell.intake import unmeasured_track
from sara_app.errors import InputError
from sara_app.human.conformance import Monitor, Violation
from sara_app.human.stated_velocity import reconcile
from sara_app.runtime.people import ingest_skeleton
from sara_app.scenario import load_scenario, parse_scenario


def _in_ball(x: np.ndarray, c: np.ndarray, r: float) -> np.ndarray:
    return np.linalg.norm(x - c, axis=-1) <= r + 1e-9


def test_the_ball_used_encloses_every_velocity_both_claims_allow() -> None:
    """Random pairs of balls (disjoint, overlapping, nested, equal centres): points sampled in
    the lens lie in the ball returned, its radius is at most the smaller claim's, and a
    contradiction is reported exactly where no point lies in both."""
    rng = np.random.default_rng(7)
    J = 400
    v_s = rng.normal(0.0, 1.0, (J, 3))
    v_e = v_s + rng.normal(0.0, 1.0, (J, 3)) * rng.choice([0.0, 0.05, 1.0, 3.0], (J, 1))
    dv_s = rng.uniform(0.02, 2.0, J)
    dv_e = rng.uniform(0.02, 2.0, J)
    v, dv, contradicted, gap = reconcile(v_s, dv_s, v_e, dv_e)
    assert (dv <= np.minimum(dv_s, dv_e) + 1e-12)[~contradicted].all()
    np.testing.assert_allclose(gap, np.linalg.norm(v_e - v_s, axis=1))
    for j in range(J):
        small, big = ((v_s[j], dv_s[j]), (v_e[j], dv_e[j]))[:: 1 if dv_s[j] <= dv_e[j] else -1]
        u = rng.normal(size=(4000, 3))
        u *= (rng.uniform(size=(4000, 1)) ** (1 / 3)) / np.linalg.norm(u, axis=1, keepdims=True)
        pts = small[0] + small[1] * u  # uniform in the smaller ball
        lens = pts[_in_ball(pts, *big)]
        if contradicted[j]:
            assert len(lens) == 0 and gap[j] > dv_s[j] + dv_e[j]
            assert np.array_equal(v[j], v_e[j]) and dv[j] == dv_e[j]  # the estimate
            continue
        assert _in_ball(lens, v[j], dv[j]).all(), j
        # the smaller sphere's points inside the other ball: the lens's extreme points
        rim = small[0] + small[1] * u / np.maximum(np.linalg.norm(u, axis=1, keepdims=True), 1e-12)
        rim = rim[_in_ball(rim, *big)]
        assert _in_ball(rim, v[j], dv[j]).all(), j
    kinds = {
        "contradicted": contradicted.sum(),
        "lens ball": (dv < np.minimum(dv_s, dv_e) - 1e-12).sum(),
    }
    assert all(n > 10 for n in kinds.values()), kinds  # every case is exercised


def test_the_compiled_step_matches_the_numpy_version() -> None:
    """Every case (either bound infinite, contradicted, nested, lens, equal centres) gives the
    oracle's balls, flags and gaps."""
    rng = np.random.default_rng(11)
    J = 2000
    v_s = rng.normal(0.0, 1.0, (J, 3))
    v_e = v_s + rng.normal(0.0, 1.0, (J, 3)) * rng.choice([0.0, 0.05, 1.0, 3.0], (J, 1))
    dv_s = np.where(rng.random(J) < 0.1, np.inf, rng.uniform(0.02, 2.0, J))
    dv_e = np.where(rng.random(J) < 0.1, np.inf, rng.uniform(0.02, 2.0, J))
    got, want = reconcile(v_s, dv_s, v_e, dv_e), reconcile_reference(v_s, dv_s, v_e, dv_e)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-12, atol=1e-12)
    with pytest.raises(InputError):
        reconcile(v_s[:3], dv_s[:3], v_e[:2], dv_e[:3])


def test_without_an_estimate_the_stated_ball_is_used_and_a_held_joint_keeps_none() -> None:
    v_s = np.array([[0.5, 0.0, 0.0], [0.0, 0.0, 0.0]])
    v_e = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    v, dv, contradicted, _ = reconcile(v_s, np.array([0.04, np.inf]), v_e,
                                       np.array([np.inf, np.inf]))  # fmt: skip
    assert not contradicted.any()
    np.testing.assert_array_equal(v[0], v_s[0])
    assert dv[0] == 0.04 and dv[1] == np.inf


def test_a_contradiction_joins_the_frames_other_violations() -> None:
    m = Monitor(("head", "neck"), np.full(2, 2.0), np.full(2, 20.0))
    m.last, m.last_violation_s = [Violation("head", "speed", 3.0, 2.0, 1.0)], 1.0
    m.contradicted(1.0, np.array([False, True]), np.array([0.0, 2.5]), np.array([1.0, 1.0]))
    assert [v.quantity for v in m.last] == ["speed", "stated_velocity"]
    m.contradicted(2.0, np.array([True, False]), np.array([2.0, 0.0]), np.array([1.0, 1.0]))
    assert [(v.joint, v.quantity, v.t_s) for v in m.last] == [("head", "stated_velocity", 2.0)]
    assert m.counts["stated_velocity"] == 2


STANDING = np.array(
    [
        (0, 0, 1.65), (0, 0, 1.45), (0, 0, 0.95), (0, 0.18, 1.42), (0, -0.18, 1.42),
        (0, 0.22, 1.15), (0, -0.22, 1.15), (0, 0.24, 0.9), (0, -0.24, 0.9), (0, 0.1, 0.92),
        (0, -0.1, 0.92), (0, 0.1, 0.5), (0, -0.1, 0.5), (0, 0.1, 0.08), (0, -0.1, 0.08),
    ]
)  # fmt: skip


def _cell(trust: bool):  # type: ignore[no-untyped-def]
    data = load_scenario("punches").model_dump(mode="json")
    data["humans"] = []
    data["inputs"]["trust_stated_velocities"] = trust
    return build_cell(parse_scenario(data, "punches_stated"))


@pytest.fixture(scope="module")
def cell():  # type: ignore[no-untyped-def]
    """The default: stated velocities checked, not trusted."""
    return _cell(False)


@pytest.fixture(scope="module")
def trusting():  # type: ignore[no-untyped-def]
    return _cell(True)


def _sway(cell, sign: float | None, rate_hz: float = 100.0, seconds: float = 2.0):  # type: ignore[no-untyped-def]
    """A person swaying sideways (0.3 m, 0.8 Hz: up to 1.5 m/s, 7.6 m/s^2) with stated
    velocities ``sign`` times the true ones (None: none stated); per frame the fault, the
    velocity used, its bound and the true velocity."""
    p = cell.params
    track = unmeasured_track("h", p.delta_y_m, p.v_max_mps, p.a_max_mps2,
                             cell.scenario.inputs.gate.intake())  # fmt: skip
    w, out = 2 * math.pi * 0.8, []
    for k in range(int(seconds * rate_hz)):
        t = 100.0 + k / rate_hz
        shift = np.array([1.5, 0.3 * math.sin(w * t), 0.0])
        v_true = np.array([0.0, 0.3 * w * math.cos(w * t), 0.0])
        v = None if sign is None else np.tile(sign * v_true, (len(STANDING), 1))
        msg = SkeletonMsg.from_arrays("full", STANDING + shift, seq=k, stamp_s=t, v_mps=v)
        assert ingest_skeleton(cell, track, msg) is None
        st = track.state
        out.append((track.intake.fault("h"), st.v.copy(), st.dv.copy(), v_true))
    return out


def test_honest_velocities_are_never_refused_and_the_ball_used_holds_the_truth(
    cell, trusting
) -> None:  # type: ignore[no-untyped-def]
    for c in (cell, trusting):
        frames = _sway(c, 1.0)
        assert all(f is None for f, *_ in frames)
        for _, v, dv, v_true in frames:
            assert (np.linalg.norm(v - v_true, axis=1) <= dv + 1e-9).all()
    # trusted, narrower than the estimate alone: the stated bound (delta_v) is used
    assert max(float(dv.max()) for _, _, dv, _ in frames[10:]) <= cell.params.delta_v_mps + 1e-12


def test_untrusted_velocities_leave_the_estimate_as_it_is(cell, trusting) -> None:  # type: ignore[no-untyped-def]
    """By default the velocity used is the positions' estimate whatever is stated: the sway's
    reversed velocities give the same balls as no velocities at all, which hold the truth where
    a trusting cell, at the slow frames the positions cannot contradict, uses the wrong ones."""
    plain = _sway(cell, None)
    for sign in (-1.0, 1.0):
        for (_, v, dv, _), (_, v0, dv0, _) in zip(_sway(cell, sign), plain, strict=True):
            np.testing.assert_array_equal(dv, dv0)
            np.testing.assert_array_equal(v, v0)
    trusted_misses = sum(
        int((np.linalg.norm(v - vt, axis=1) > dv + 1e-9).sum())
        for f, v, dv, vt in _sway(trusting, -1.0) if f is None
    )  # fmt: skip
    assert trusted_misses > 0  # what the default avoids


@pytest.mark.parametrize("trust", [False, True])
def test_reversed_velocities_fault_the_person_and_the_estimate_is_used(
    cell, trusting, trust: bool
) -> None:  # type: ignore[no-untyped-def]
    """The hostile-tracker probe's reversed velocities: the person is a fault (the robot stays
    on its failsafe) while they move fast enough for the positions to contradict them, and a
    contradicted joint's velocity is the estimate's, which holds the truth. (A joint whose
    estimate's bound is wider than twice its speed is not contradicted: trusted as stated.)"""
    frames = _sway(trusting if trust else cell, -1.0)
    faults = [f for f, *_ in frames if f is not None]
    assert faults and all("stated_velocity" in f for f in faults)
    fast = [k for k, (*_, vt) in enumerate(frames) if np.linalg.norm(vt) > 1.2 and k > 10]
    assert fast and all(frames[k][0] is not None for k in fast)
    refused = 0
    for k in fast:
        _, v, dv, v_true = frames[k]
        estimated = dv > cell.params.delta_v_mps + 1e-12  # the stated ball refused
        refused += int(estimated.sum())
        assert (np.linalg.norm(v - v_true, axis=1) <= dv + 1e-9)[estimated].all()
    assert refused > len(fast)


def test_a_contradiction_reaches_the_verdict_and_the_dashboard() -> None:
    """Verdict schema version 4: a ``stated_velocity`` violation and its tracking count
    validate and round-trip, and the dashboard names it in m/s."""
    import json

    from sara_app.bus.codec import Decoder
    from sara_app.bus.examples import example_messages
    from sara_app.bus.messages import VerdictMsg, encode
    from sara_app.dashboard.status_text import _people_rows
    from sara_app.runtime.messages import violation_msgs

    key, example = example_messages()["verdict"]
    found = [("p1", Violation("r_wrist", "stated_velocity", 2.6, 1.42, 12.5))]
    data = json.loads(encode(example))
    data["violations"] = [v.model_dump() for v in violation_msgs(found)]
    data["tracking"] = {"p1": {"stated_velocity": 3}}
    msg = VerdictMsg.model_validate(data)
    assert msg.schema_version == 4 and msg.violations[0].quantity == "stated_velocity"
    assert Decoder().decode(key, encode(msg)).msg == msg
    rows = _people_rows({"violations": data["violations"]})
    assert any("stated_velocity 2.60 > 1.42 m/s" in text for _, text in rows), rows
