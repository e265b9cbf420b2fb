"""The history property (issue "No input history may hide a person"): once a person has been
measured standing at P for ``SETTLE_S``, whatever came before (jumps of any size, swaps with
another person, whole-skeleton freezes with fresh stamps, gaps, clock skew within the
tolerance, one-frame spikes), the verdict for that person is at least as conservative as for a
fresh person measured at P over the same time (taken at face value: without the gate's
anatomy check, which holds more of a fresh skeleton than of one with a history), in SSM and
PFL with the default models.

Both people go through :func:`sara_app.runtime.people.ingest_skeleton`, the worker's own path; the
verdicts are the shield's, on the same robot states (several points of the task, moving).
Failed on the code before the fix: a joint the gate blamed for a bone after a jump was held at
its old place (the measurement discarded), and the velocity measured across a whole-skeleton
jump centred the acceleration models far from the person.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from sara_app.bus.messages import SkeletonMsg
from sara_app.cell.build import Cell, build_cell
from sara_app.cell.intake import Track
from sara_app.human.intake import SETTLE_S
from sara_app.runtime.people import ingest_skeleton
from sara_app.safety.shield import Shield
from sara_app.scenario import load_scenario, parse_scenario

STANDING = np.array(
    [
        (0, 0, 1.65), (0, 0, 1.45), (0, 0, 0.95), (0, 0.18, 1.42), (0, -0.18, 1.42),
        (0, 0.22, 1.15), (0, -0.22, 1.15), (0, 0.24, 0.9), (0, -0.24, 0.9), (0, 0.1, 0.92),
        (0, -0.1, 0.92), (0, 0.1, 0.5), (0, -0.1, 0.5), (0, 0.1, 0.08), (0, -0.1, 0.08),
    ]
)  # fmt: skip
SKEW_S = 0.0015  # within the contract's 2 ms future tolerance


def _cell(mode: str) -> Cell:
    data = load_scenario("punches").model_dump(mode="json")
    data["humans"] = []
    data["shield"] = {"mode": mode, "dt_s": 0.002}  # the default models
    return build_cell(parse_scenario(data, f"punches_{mode}"))


def _robot_states(shield: Shield, n: int) -> list[Any]:
    """Copies of the follower at ``n`` points of the task, moving (nobody in the cell)."""
    out = []
    for k in range(n * 150):
        shield.cycle(0.0, [])
        if k % 150 == 149:
            out.append(copy.deepcopy(shield.follower))
    return out


@pytest.fixture(scope="module")
def cells() -> dict[str, tuple[Cell, list[Any]]]:
    out = {}
    for mode in ("ssm", "pfl"):
        cell = _cell(mode)
        out[mode] = (cell, _robot_states(cell.shield, 5))
    return out


def _pose(x: float, y: float, yaw: float, scale: float = 1.0) -> np.ndarray:
    """A person of height ``1.75 scale`` m standing at ``(x, y)`` turned by ``yaw``."""
    c, s = math.cos(yaw), math.sin(yaw)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return scale * STANDING @ R.T + [x, y, 0.0]


@dataclass
class Frame:
    stamp_s: float
    y: np.ndarray


sizes = st.sampled_from([1.0, 1.0, 0.85, 1.12])  # swaps: people of other sizes
places = st.tuples(st.floats(-3.0, 3.0), st.floats(-3.0, 3.0), st.floats(-math.pi, math.pi), sizes)
near = st.tuples(st.floats(0.4, 1.6), st.floats(-0.6, 0.6), st.floats(-math.pi, math.pi), sizes)
# the final skeleton as measured may be off a person's shape: one joint measured elsewhere (a
# tracker that associates a wrist with another person's, a marker on the wrong body), here at
# a point of the robot's workspace
offsets = st.one_of(
    st.none(),
    st.tuples(
        st.integers(0, 14),
        st.tuples(st.floats(0.2, 0.8), st.floats(-0.8, 0.8), st.floats(0.1, 0.9)),
    ),
)
events = st.one_of(
    st.tuples(st.just("stand"), places, st.floats(0.02, 0.6)),  # a jump there, then standing
    st.tuples(st.just("walk"), places, st.floats(0.05, 1.0)),  # walking there at <= 1.5 m/s
    st.tuples(st.just("swap"), places, st.floats(0.02, 0.5)),  # another person's skeleton
    st.tuples(st.just("freeze"), st.just((0.0, 0.0, 0.0, 1.0)), st.floats(0.02, 0.6)),
    st.tuples(st.just("gap"), st.just((0.0, 0.0, 0.0, 1.0)), st.floats(0.02, 0.5)),
    st.tuples(st.just("spike"), places, st.floats(0.0, 0.0)),  # one joint, one frame
)


def _history(
    evs: list[tuple[str, tuple[float, ...], float]],
    final: tuple[float, ...],
    at: tuple[int, tuple[float, float, float]] | None,
    rate_hz: float,
    seed: int,
    delta_y_m: float,
) -> tuple[list[Frame], list[Frame]]:
    """The frames of the history, then of the final stand at ``final`` for ``SETTLE_S``:
    noise within ``delta_y`` (uniform in a cube), stamps skewed within the tolerance."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    t, here = 100.0, _pose(0.0, -2.0, 0.0)
    frames: list[Frame] = []

    def emit(y: np.ndarray) -> None:
        noise = rng.uniform(-1, 1, y.shape) * 0.9 * delta_y_m / math.sqrt(3.0)
        frames.append(Frame(t + rng.uniform(-SKEW_S, SKEW_S), y + noise))

    for kind, place, dur in evs:
        n = max(1, int(dur * rate_hz))
        target = _pose(*place)
        if kind == "spike":
            y = here.copy()
            y[int(rng.integers(len(y)))] += rng.uniform(-0.5, 0.5, 3)
            emit(y)
            t += dt
            continue
        if kind == "walk":  # every joint along a straight line at most 1.5 m/s
            step = 1.5 * dt
            while np.abs(target - here).max() > 1e-9:
                d = target - here
                here = here + d * min(1.0, step / max(np.linalg.norm(d, axis=1).max(), 1e-12))
                emit(here)
                t += dt
            continue
        for _ in range(n):
            if kind == "freeze":
                frames.append(Frame(t, frames[-1].y.copy()) if frames else Frame(t, here))
            elif kind == "swap":
                emit(target)
            elif kind == "stand":
                emit(target)
            t += dt
        if kind == "stand":
            here = target
    t += dt
    start = len(frames)
    here = _pose(*final)
    if at is not None:
        here[at[0]] = at[1]
    for _ in range(int(math.ceil(SETTLE_S * rate_hz)) + 1):
        emit(here)
        t += dt
    return frames, frames[start:]


def _feed(cell: Cell, hid: str, frames: list[Frame], anatomy: bool = True) -> Track:
    track = _new_track(cell, hid, anatomy)
    last = -math.inf
    for f in frames:
        stamp = max(f.stamp_s, last + 1e-6)  # skew never reorders a tracker's stamps
        last = stamp
        msg = SkeletonMsg.from_arrays("full", f.y, seq=0, stamp_s=stamp)
        ingest_skeleton(cell, track, msg)
    return track


def _new_track(cell: Cell, hid: str, anatomy: bool = True) -> Track:
    from sara_app.cell.intake import unmeasured_track

    p = cell.params
    s = cell.scenario.inputs.gate.intake()
    s = dataclasses.replace(s, gate=dataclasses.replace(s.gate, anatomy=anatomy))
    return unmeasured_track(hid, p.delta_y_m, p.v_max_mps, p.a_max_mps2, s)


def _verdicts(cell: Cell, follower: Any, track: Track, t_now: float) -> tuple[str, Any]:
    """This person's verdict alone on the robot state ``follower``: ``fault``, ``verified``
    or ``failsafe``, and the check's result (None for a fault)."""
    shield = cell.shield
    faults: list[str] = []
    fault = track.intake.fault(track.state.id)
    if fault:
        return "fault", None
    ages: dict[str, float] = {}
    usable = shield._check_humans(t_now, [track.state], faults, ages)
    if faults or not usable:
        return "fault", None
    shield.follower = copy.deepcopy(follower)
    saved = {k: getattr(shield, k) for k in ("cap", "_calm") if hasattr(shield, k)}
    hum = shield._human_arrays([track.state], usable, ages)
    *_, verified = shield._plan_and_verify(hum)
    res = shield._res
    for k, v in saved.items():
        setattr(shield, k, v)
    return ("verified" if verified else "failsafe"), res


@settings(
    max_examples=int(os.environ.get("SARA_HISTORY_EXAMPLES", "120")),
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture],
)
@given(
    evs=st.lists(events, min_size=1, max_size=6),
    final=near,
    at=offsets,
    arrive=st.sampled_from(["walk", "stand", "as_drawn"]),
    rate_hz=st.sampled_from([30.0, 60.0, 120.0]),
    seed=st.integers(0, 2**31),
    latency_s=st.floats(0.0, 0.02),
)
@example(  # found in a CI-like run: bones learned on another body made the gate distrust the
    # neck and pelvis in one settling frame; the velocity estimate fell back to another lag and
    # its differently centred set cleared the torso on an interval where a fresh person's did not
    evs=[("spike", (0.0, 0.0, 0.0, 1.0), 0.0), ("spike", (0.0, 0.0, 0.0, 1.0), 0.0)],
    final=(0.59375, -0.49609375, 3.0, 0.85),
    at=None,
    arrive="walk",
    rate_hz=60.0,
    seed=2147483647,
    latency_s=0.009765625,
)
@example(  # found in CI: after a freeze the gate distrusted a hip (another body's bones) in a
    # settling frame; its combined ball fell back to R_VEL's, centred on the measurement, and the
    # thigh's capsule to the knee's shifted ball cleared an interval that the capsule with the
    # hip's estimate did not (capsules are not monotone in one joint's ball): the combined model
    # now makes no claim for a part whose joint has no estimate
    evs=[
        ("walk", (2.109375, 0.0, 0.75, 1.12), 1.0),
        ("stand", (-0.25, 0.375, 1.0, 1.12), 0.2265625),
        ("walk", (2.09375, 0.0, 0.75, 1.12), 1.0),
        ("freeze", (0.0, 0.0, 0.0, 1.0), 0.5),
    ],
    final=(0.875, 0.5, 0.0, 0.85),
    at=None,
    arrive="stand",
    rate_hz=120.0,
    seed=5620,
    latency_s=0.0,
)
@example(  # found in CI (2026-12-05): the gate refused 7 of the settling frames (bones learned
    # on another body); skipped by the estimator, they let the torso's joints reach across them
    # to a frame 0.8 s old, and the shorter lag left centred the set otherwise than a fresh
    # person's: it cleared the torso on an interval where the fresh one did not
    evs=[
        ("walk", (0.0, 2.34375, 0.0, 1.12), 1.0),
        ("walk", (1.0, -2.0, 0.75, 0.85), 1.0),
        ("swap", (0.0, 0.0, 0.0, 1.0), 0.0625),
        ("spike", (0.0, 0.0, 0.0, 1.0), 0.0),
    ],
    final=(1.0, 0.0, 0.0, 0.85),
    at=None,
    arrive="walk",
    rate_hz=30.0,
    seed=203506,
    latency_s=0.01953125,
)
def test_no_history_makes_a_person_at_p_less_conservative_than_a_fresh_one(
    cells, evs, final, at, arrive, rate_hz, seed, latency_s
) -> None:
    if arrive != "as_drawn":  # the person walked (or was) there before the final frames
        evs = [*evs, (arrive, final, 0.3)]
    for mode, (cell, followers) in cells.items():
        frames, settle = _history(evs, final, at, rate_hz, seed, cell.params.delta_y_m)
        # the fresh person takes the final skeleton at face value (no anatomy check: with it,
        # a joint measured off the body holds both ends of its bones, unbounded without a
        # history, more conservative than any history can be)
        history, fresh = _feed(cell, "p1", frames), _feed(cell, "p1", settle, anatomy=False)
        assert history.state.stamp_s is not None and fresh.state.stamp_s is not None
        t_now = max(f.stamp_s for f in frames) + latency_s
        for follower in followers:
            v_hist, r_hist = _verdicts(cell, follower, history, t_now)
            v_fresh, r_fresh = _verdicts(cell, follower, fresh, t_now)
            assert v_hist != "verified" or v_fresh == "verified", (mode, v_hist, v_fresh)
            if mode == "ssm" and v_hist != "fault":
                # on one trajectory: every body part the history's sets clear on an interval,
                # the fresh person's sets clear there too
                clear_h, clear_f = (
                    _parts_clear(cell, follower, tr, t_now) for tr in (history, fresh)
                )
                assert not (clear_h & ~clear_f).any(), mode


def _parts_clear(cell: Cell, follower: Any, track: Track, t_now: float) -> np.ndarray:
    """``(K, P)`` the body parts some model clears on each interval of the follower's shielded
    trajectory at full speed."""
    shield = cell.shield
    shield.follower = copy.deepcopy(follower)
    traj, ends, radius = shield._shielded()
    h = track.state
    w = None if h.widen_m is None else h.widen_m[None]
    age = np.array([max(t_now - float(h.stamp_s or 0.0), 0.0)])
    res = shield.verifier.verify(h.y[None], h.v[None], h.dv[None], age, traj.times, ends, radius, w)
    return res.parts_clear[0]
