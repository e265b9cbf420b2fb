"""The conformance monitor: silent on motion within the bounds (its checks are necessary
conditions), and a person beyond them is a fault until they have kept within for recover_s."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sara_app.errors import ParameterError
from sara_app.human.conformance import Monitor
from sara_app.human.intake import Intake
from sara_app.human.tracking_settings import GateSettings, IntakeSettings

DY = 0.004
J = 15
SYNTHETIC = IntakeSettings(GateSettings(anatomy=False), recover_s=0.5)
"""Points moving each on its own (no body): the gate's anatomy check off."""


def _bang_bang(seed: int, a_max: float, v_max: float, T: int = 360, rate_hz: float = 120.0):
    """Points ``(T, J, 3)`` under bang-bang acceleration at ``a_max``, speed kept <= v_max."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    v = np.zeros(J * 3).reshape(J, 3)
    y = np.zeros((T, J, 3))
    direction = rng.normal(size=(J, 3))
    for k in range(1, T):
        if k % 9 == 0:
            direction = rng.normal(size=(J, 3))
        a = a_max * direction / np.linalg.norm(direction, axis=1, keepdims=True)
        v_new = v + a * dt
        speed = np.linalg.norm(v_new, axis=1, keepdims=True)
        v_new = np.where(speed > v_max, v_new * v_max / speed, v_new)
        y[k] = y[k - 1] + 0.5 * (v + v_new) * dt  # exact for a linear velocity change
        v = v_new
    noise = rng.normal(size=y.shape)
    noise *= DY * rng.random((T, J, 1)) / np.linalg.norm(noise, axis=-1, keepdims=True)
    return np.arange(T) * dt, y + noise


@pytest.mark.parametrize("seed", range(3))
def test_motion_within_the_bounds_is_never_a_violation(seed: int) -> None:
    a_max, v_max = 40.0, 1.5
    t, y = _bang_bang(seed, a_max, v_max)
    intake = Intake(DY, np.full(J, v_max), np.full(J, a_max), SYNTHETIC)
    for k in range(len(t)):
        intake.take(float(t[k]), y[k], DY, J)  # points: no bones to learn
    assert not any(intake.monitor.counts.values()), intake.monitor.counts
    assert intake.fault("p") is None


def test_too_fast_is_a_fault_until_recover_s_within_bounds() -> None:
    t, y = _bang_bang(0, 40.0, 3.0)  # 3 m/s against a bound of 1.5
    intake = Intake(DY, np.full(J, 1.5), np.full(J, 40.0), SYNTHETIC)
    faults = []
    for k in range(len(t)):
        intake.take(float(t[k]), y[k], DY, J)
        faults.append(intake.fault("p"))
    assert intake.monitor.counts["speed"] > 0
    worst = max(intake.monitor.last, key=lambda v: v.value)
    assert worst.quantity == "speed" and worst.value > worst.bound == 1.5
    assert any(f and "speed" in f and "> bound 1.50" in f for f in faults)
    # then the person stands still (noise only; the abrupt stop is itself a violation): while
    # the newest measurement disagrees with the history the gate keeps (the joints' last trusted
    # places, out of reach at the bound) it is a violation; the fault lifts recover_s after the
    # last one
    t0, rest = float(t[-1]), y[-1]
    rng = np.random.default_rng(5)
    cleared, agreed_s = [], None
    for k in range(1, 361):
        tk = t0 + k / 120
        intake.take(tk, rest + rng.uniform(-1, 1, rest.shape) * DY / 2, DY, J)
        if agreed_s is None and intake.gate.out.trusted.all():
            agreed_s = tk
        last_v = intake.monitor.last_violation_s
        if abs(tk - last_v - 0.5) > 1e-9:  # off the boundary, where rounding decides
            assert (intake.fault("p") is None) == (tk - last_v > 0.5)
        cleared.append(intake.fault("p") is None)
    assert agreed_s is not None and last_v < agreed_s and cleared[-1]


def test_accelerating_beyond_a_max_is_an_acceleration_violation() -> None:
    t, y = _bang_bang(1, 400.0, 1.4)  # within v_max, ten times a_max
    intake = Intake(DY, np.full(J, 1.5), np.full(J, 40.0), SYNTHETIC)
    for k in range(len(t)):
        intake.take(float(t[k]), y[k], DY, J)
    assert intake.monitor.counts["acceleration"] > 0
    assert intake.monitor.counts["speed"] == 0


def test_recover_s_is_checked() -> None:
    with pytest.raises(ParameterError, match="recover_s"):
        Monitor(("a",), np.ones(1), np.ones(1), recover_s=0.0)


@given(st.integers(0, 2**31 - 1))
@settings(max_examples=40, deadline=None)
def test_the_compiled_frame_step_equals_the_numpy_reference(seed: int) -> None:
    """Random frames (jittered stamps, joints distrusted at random, jumps): the kernel's rings,
    speeds and accelerations equal the plain numpy oracle's at every frame."""
    from conformance_reference import observe_frame_reference

    from sara_app.human.conformance_kernels import observe_frame

    rng = np.random.default_rng(seed)
    J, N = 15, 17
    rings = [(np.full(N, -np.inf), np.zeros((N, J, 3)), np.zeros((N, J), bool)) for _ in range(2)]
    speed, acc, rise = np.zeros(J), np.zeros(J), np.zeros(J)
    t, y = 0.0, rng.normal(size=(J, 3))
    for _ in range(40):
        t += rng.uniform(0.005, 0.02)
        y = y + rng.normal(scale=rng.choice([0.001, 0.05]), size=(J, 3))
        trusted = rng.random(J) > 0.2
        jump = np.where(rng.random(J) > 0.9, rng.uniform(0, 5, J), 0.0)
        dy = float(rng.uniform(0, 0.01))
        observe_frame(*rings[0], t, y, trusted, dy, jump, speed, acc, rise)
        s_ref, a_ref, r_ref = observe_frame_reference(*rings[1], t, y, trusted, dy, jump)
        np.testing.assert_allclose(speed, s_ref, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(rise, r_ref, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(acc, a_ref, rtol=1e-12, atol=1e-6)
        for a, b in zip(rings[0], rings[1], strict=True):
            np.testing.assert_array_equal(a, b)
