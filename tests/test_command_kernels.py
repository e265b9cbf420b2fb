"""The command's body as one compiled call (``sara_app.runtime.command_kernels``) against the
numpy composition it replaced (the oracle here): the set point, then the held stop's samples
after the step; the status says what the schema would refuse (non-finite values, a stop whose
times do not increase)."""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.runtime.command_kernels import FINITE, ORDER, command_body


def _oracle(now, dt, q, v, a, held):
    """The numpy version: ``(status, body)``."""
    if held is None:
        t, q_stop = np.empty(0), np.empty((0, len(q)))
    else:
        times, qs = held
        later = times > now + dt + 1e-9
        t = np.concatenate(([dt], times[later] - now))
        q_stop = np.vstack((q, qs[later]))
    body = np.concatenate((q, v, a, t, q_stop.ravel()))
    if not np.isfinite(body).all():
        return FINITE, body
    if len(t) > 1 and not (np.diff(t) > 0.0).all():
        return ORDER, body
    return 0, body


def _case(rng: np.random.Generator, n: int):
    now = 1000.0 + rng.uniform(0, 10)
    dt = rng.choice([0.001, 0.002, 0.004])
    q, v, a = (rng.normal(size=n) for _ in range(3))
    held = None
    if rng.random() < 0.8:
        K = int(rng.integers(1, 30))
        start = now + rng.uniform(-3 * dt, 2 * dt)  # some samples before the step's end
        times = start + np.cumsum(rng.uniform(0.0005, 0.02, K))
        if rng.random() < 0.1:
            times[rng.integers(K)] = now + dt  # exactly at the step's end: not later
        held = (times, rng.normal(size=(K, n)))
    fault = rng.random()
    if fault < 0.1:
        (q, v, a)[rng.integers(3)][rng.integers(n)] = rng.choice([np.nan, np.inf, -np.inf])
    elif fault < 0.2 and held is not None:
        held[1][rng.integers(len(held[0])), rng.integers(n)] = np.nan
    elif fault < 0.3 and held is not None and len(held[0]) > 2:
        k = int(rng.integers(1, len(held[0])))
        held[0][k] = held[0][k - 1]  # repeats a time
    return now, dt, q, v, a, held


@pytest.mark.parametrize("n", [1, 6, 7])
def test_the_kernel_is_the_numpy_composition(n: int) -> None:
    rng = np.random.default_rng(n)
    seen = set()
    for _ in range(3000):
        now, dt, q, v, a, held = _case(rng, n)
        want_status, want = _oracle(now, dt, q, v, a, held)
        times, qs = held if held is not None else (np.empty(0), np.empty((0, n)))
        status, body = command_body(now, dt, q, v, a, held is not None, times, qs)
        assert status == want_status
        seen.add(status)
        if status != FINITE:  # NaN compares unequal; the status is what matters then
            np.testing.assert_array_equal(body, want)
    assert seen == {0, FINITE, ORDER}


def test_the_body_is_a_new_array() -> None:
    q = np.arange(3.0)
    held = (np.array([1000.01, 1000.02]), np.ones((2, 3)))
    _, b1 = command_body(1000.0, 0.002, q, q, q, True, *held)
    _, b2 = command_body(1000.0, 0.002, q, q, q, True, *held)
    assert b1 is not b2 and not np.shares_memory(b1, q)
    b1[0] = 99.0
    assert q[0] == 0.0 and b2[0] == 0.0
