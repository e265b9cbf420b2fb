"""The velocity estimator's error bound holds for acceleration-bounded motion with noise."""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.errors import InputError
from sara_app.human.velocity import VelocityEstimator, estimate_recording


@pytest.mark.parametrize("seed", range(5))
def test_error_bound_holds(seed: int) -> None:
    rng = np.random.default_rng(seed)
    dt, T, J = 1 / 120, 240, 6
    a_max = np.full(J, 50.0)
    dy = 0.004
    t = np.arange(T) * dt
    # bang-bang acceleration at its bound, switching every few frames
    acc = rng.choice([-1.0, 1.0], size=(T, J, 3)) / np.sqrt(3) * a_max[None, :, None]
    acc = np.repeat(acc[::7], 7, axis=0)[:T]
    v = np.cumsum(acc * dt, axis=0) + rng.normal(size=(1, J, 3))
    y = np.cumsum(v * dt, axis=0)  # exact for piecewise-constant v; v(t_i) is the rate at i
    # The true velocity of the piecewise-linear path y at t_i (left derivative) is v[i].
    noise = rng.normal(size=y.shape)
    noise *= dy * rng.random((T, J, 1)) / np.linalg.norm(noise, axis=-1, keepdims=True)
    v_hat, bound = estimate_recording(t, y + noise, dy, a_max)
    err = np.linalg.norm(v_hat - v, axis=-1)
    assert np.all(err[1:] <= bound[1:] + 1e-9)
    assert np.isinf(bound[0]).all()


def test_streaming_matches_batch_and_rejects_time_going_backwards() -> None:
    rng = np.random.default_rng(0)
    t = np.arange(30) / 100
    y = rng.normal(size=(30, 4, 3))
    a = np.full(4, 30.0)
    v_b, b_b = estimate_recording(t, y, 0.004, a)
    est = VelocityEstimator(4, 0.004, a)
    for i in range(30):
        v_s, b_s = est.update(float(t[i]), y[i])
        if i:
            np.testing.assert_allclose(v_s, v_b[i])
            np.testing.assert_allclose(b_s, b_b[i])
    with pytest.raises(InputError, match="does not advance"):
        est.update(float(t[10]), y[10])


def test_a_distrusted_frame_at_the_best_lag_leaves_no_estimate_not_another_lag() -> None:
    """The estimate depends on the stamps and the two frames of the best lag only: a joint
    whose frame at that lag the gate distrusted has none for this frame (infinite bound), the
    other joints the very estimate they get when all is trusted; offline and streaming agree."""
    rng = np.random.default_rng(3)
    T, J = 12, 4
    t = np.arange(T) / 60.0 + rng.uniform(-1e-3, 1e-3, T)
    y = np.cumsum(rng.normal(scale=0.01, size=(T, J, 3)), axis=0)
    a_max = np.full(J, 40.0)
    v_all, dv_all = estimate_recording(t, y, 0.004, a_max)
    trusted = np.ones((T, J), bool)
    est = VelocityEstimator(J, 0.004, a_max)
    for k in range(T - 1):
        est.update(float(t[k]), y[k])
    # the frame the last one's best lag reaches, distrusted for joint 0
    lags = np.arange(1, 9)
    best = int(np.argmin(2 * 0.004 / (t[-1] - t[-1 - lags]) + 20.0 * (t[-1] - t[-1 - lags])))
    trusted[T - 1 - lags[best], 0] = False
    v, dv = estimate_recording(t, y, 0.004, a_max, trusted=trusted)
    assert dv[-1, 0] == np.inf and np.isfinite(dv_all[-1, 0])
    np.testing.assert_array_equal(v[-1, 1:], v_all[-1, 1:])
    np.testing.assert_array_equal(dv[-1, 1:], dv_all[-1, 1:])
    est.trusted[lags[best] - 1, 0] = False  # as the gate said when that frame came
    v_s, dv_s = est.update(float(t[-1]), y[-1])
    assert dv_s[0] == np.inf
    np.testing.assert_allclose(v_s[1:], v_all[-1, 1:])
