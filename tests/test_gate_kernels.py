"""The gate's compiled frame check (``sara_app.human.gate_kernels``) against its numpy oracle
(``tests/gate_reference.py``): random skeleton streams with every glitch the gate knows
(spikes, swapped and frozen markers, missing joints, a whole repeated skeleton, too-fast
joints, upper-body sources) give the same result and the same gate state at every frame."""

from __future__ import annotations

import numpy as np
import pytest
from gate_reference import ReferenceGate, reference_repeated
from hypothesis import given, settings
from hypothesis import strategies as st

from sara_app.errors import InputError
from sara_app.human.gate import Gate
from sara_app.human.gate_kernels import repeated_frame
from sara_app.human.scripted import joints, standing
from sara_app.human.tracking_settings import GateSettings


def _same_gate(a: Gate, b: Gate, frame: int) -> None:
    for name in ("y", "extra_m", "trusted", "flags", "jump_speed_mps"):
        np.testing.assert_allclose(getattr(a.out, name), getattr(b.out, name), rtol=1e-12,
                                   atol=1e-12, err_msg=f"out.{name}, frame {frame}")  # fmt: skip
    assert a.out.refused == b.out.refused, frame
    for name in ("y_trusted", "t_trusted", "dy_trusted", "y_prev", "first_seen_s", "since_s",
                 "length_m"):  # fmt: skip
        np.testing.assert_array_equal(
            getattr(a, name), getattr(b, name), err_msg=f"{name}, {frame}"
        )
    assert a.counts == b.counts and a.last_flag == b.last_flag, frame


@given(st.integers(0, 2**31 - 1), st.sampled_from([(15, 15), (15, 9), (9, 9)]))
@settings(max_examples=60, deadline=None)
def test_the_compiled_check_equals_the_numpy_reference(seed: int, shape: tuple[int, int]) -> None:
    J, n_measured = shape
    rng = np.random.default_rng(seed)
    known = (("l_elbow", "l_wrist", 0.27),) if rng.random() < 0.5 else ()
    gs = GateSettings(bone_tol_m=float(rng.uniform(0.0, 0.08)), learn_frames=5,
                      max_hold_s=float(rng.uniform(0.05, 0.5)), known_bones_m=known,
                      anatomy=bool(rng.random() < 0.8))  # fmt: skip
    v_max = rng.uniform(0.5, 3.0, J)
    gates = (Gate(v_max.copy(), gs), ReferenceGate(v_max.copy(), gs))
    y = joints(standing((1.0, 0.0), 0.0))[:J]
    t = 100.0
    prev = y.copy()
    for frame in range(80):
        t += float(rng.choice([0.01, 0.01, 0.0333, 0.002]))
        y = y + rng.normal(scale=0.003, size=(J, 3))
        meas = y + rng.normal(scale=0.002, size=(J, 3))
        event = rng.random()
        missing = None
        if event < 0.1:  # a spike on one joint
            meas[rng.integers(J)] += rng.normal(scale=0.5, size=3)
        elif event < 0.2:  # frozen markers: repeat last frame's values
            k = rng.integers(1, 4)
            idx = rng.choice(J, k, replace=False)
            meas[idx] = prev[idx]
        elif event < 0.25:  # the whole skeleton repeated
            meas = prev.copy()
        elif event < 0.35:  # missing joints (NaN rows, as a tracker without them)
            missing = rng.random(J) < 0.3
            meas[missing] = np.nan
        elif event < 0.4:  # two markers swapped
            a, b = rng.choice(J, 2, replace=False)
            meas[[a, b]] = meas[[b, a]]
        elif event < 0.45:  # the whole person moves too fast
            y = y + rng.normal(scale=0.3, size=3)
            meas = y + rng.normal(scale=0.002, size=(J, 3))
        elif event < 0.5:  # no body: every joint at one point, or one limb stretched
            if rng.random() < 0.5:
                meas = meas[:1] + rng.normal(scale=0.001, size=(J, 3))
            else:
                meas[rng.integers(J)] += rng.normal(scale=0.4, size=3)
        dy = float(rng.choice([0.004, 0.012, 0.03]))
        for g in gates:
            g.check(t, meas.copy(), dy, n_measured, None if missing is None else missing.copy())
        _same_gate(gates[0], gates[1], frame)
        prev = meas


def test_a_frame_of_the_wrong_shape_is_an_input_error() -> None:
    """The kernel reads rows by index: a frame that does not fit the gate never reaches it."""
    g = Gate(np.ones(15))
    try:
        g.check(0.0, np.zeros((9, 3)), 0.01, 9)
    except InputError as e:
        assert "(9, 3)" in str(e) and "(15, 3)" in str(e)
    else:
        raise AssertionError("a (9, 3) frame passed a 15-joint gate")


@pytest.mark.parametrize("J", [15, 9])
def test_the_compiled_repeat_test_equals_the_numpy_reference(J: int) -> None:
    """Streams of frames that repeat exactly, within the tolerance, just beyond it, with NaN,
    missing joints and measured-joint counts from none to all: the same answers and the same
    kept frame."""
    rng = np.random.default_rng(J)
    raw_k, raw_r = np.full((J, 3), np.nan), np.full((J, 3), np.nan)
    y = rng.normal(size=(J, 3))
    answers = set()
    for _ in range(4000):
        kind = rng.integers(6)
        if kind == 1:
            y = y + rng.normal(scale=1e-3, size=y.shape)
        elif kind == 2:
            y = y.copy()
            y[rng.integers(J), rng.integers(3)] += rng.choice([0.5e-9, 2e-9, -2e-9])
        elif kind == 3:
            y = y.copy()
            y[rng.integers(J), rng.integers(3)] = np.nan
        elif kind == 4:
            y = rng.normal(size=(J, 3))
        missing = rng.random(J) < rng.choice([0.0, 0.2, 1.0])
        n = int(rng.choice([0, 9, J, J + 3, -1]))
        got = repeated_frame(y, raw_k, n, missing)
        want = reference_repeated(y, raw_r, n, missing)
        assert got == want
        np.testing.assert_array_equal(raw_k, raw_r)
        answers.add(got)
    assert answers == {True, False}
