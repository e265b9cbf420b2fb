"""The worker's cycle phase locked to the skeleton stream (``sara_app.runtime.cadence``): a
simulated tracker (stamps on its own frame clock, a random delay to arrival) and a simulated
cycle grid that takes every skeleton arrived by a cycle's start; the lock's law on real
numbers, no clock of the machine."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sara_app.runtime.cadence import REFERENCE_TIMEOUT_S, PhaseLock

DT = 0.002


def _simulate(
    lock: PhaseLock | None,
    cycles: int,
    trackers: dict[str, tuple[float, float]],
    delay,
    t0: float = 1000.0,
) -> tuple[list[tuple[str, float]], list[float]]:
    """Cycles from ``t0``; ``trackers``: person -> (frame period, phase) in s; ``delay(rng)``:
    stamp -> arrival (s). Returns (person, lag at first use) per skeleton and the periods."""
    rng = np.random.default_rng(0)
    queued: list[tuple[float, str, float]] = []  # (arrival, person, stamp)
    next_frame = {h: t0 + phase for h, (_, phase) in trackers.items()}
    t, lags, periods = t0, [], []
    for _ in range(cycles):
        for h, (period, _) in trackers.items():
            while next_frame[h] <= t + 0.05:
                queued.append((next_frame[h] + delay(rng), h, next_frame[h]))
                next_frame[h] += period
        stamps: dict[str, float] = {}
        for arrival, h, stamp in sorted(queued):
            if arrival <= t:
                stamps[h] = stamp  # the newest per person, as the worker drains them
        queued = [q for q in queued if q[0] > t]
        lags += [(h, t - s) for h, s in stamps.items()]
        slew = 0.0
        if lock is not None:
            lock.observe(t, stamps)
            slew = lock.slew_s()
        periods.append(DT + slew)
        t += DT + slew
    return lags, periods


def _transport(rng) -> float:
    return 3e-4 + rng.exponential(1e-4)


def _transport_quantile(q: float) -> float:
    return 3e-4 - 1e-4 * math.log(1.0 - q)


@pytest.mark.parametrize("phase", [0.0, 0.00031, 0.001, 0.0019])
def test_a_locked_grid_takes_each_skeleton_about_its_delay_quantile_after_its_stamp(
    phase: float,
) -> None:
    lock = PhaseLock(DT)
    lags, _ = _simulate(lock, 20000, {"p1": (0.01, phase)}, _transport)
    late = np.array([lag for _, lag in lags[len(lags) // 2 :]])
    q_tau = _transport_quantile(lock.quantile)
    assert abs(lock.tau_s - q_tau) < 1.5e-4, lock.tau_s
    assert np.mean(late > lock.tau_s + DT / 2) < 0.03  # missed: arrived after the locked cycle
    assert np.median(late) < q_tau + 1e-4
    # the unlocked grid, the same tracker: a skeleton waits its delay plus whatever the phase
    # leaves (up to a period); locked, never notably longer than that
    free, _ = _simulate(None, 20000, {"p1": (0.01, phase)}, _transport)
    assert np.median(late) < np.median([lag for _, lag in free]) + 1e-4


def test_the_grid_keeps_the_control_rate_whatever_the_stamps_say() -> None:
    """Adversarial stamps (random, far off, non-finite, two trackers at unrelated rates): each
    period within the slew bound, tau within its bounds, never NaN."""
    rng = np.random.default_rng(1)
    lock = PhaseLock(DT)
    t = 50.0
    for k in range(20000):
        choice = k % 5
        stamps = {
            0: {"a": t - rng.uniform(-0.01, 0.01)},
            1: {"a": float(rng.choice([math.nan, math.inf, -math.inf, t + 1e9]))},
            2: {"b": t - rng.uniform(0, 0.3), "a": t - rng.uniform(0, 0.003)},
            3: {},
            4: {"a": t - 1e-4 * (k % 37)},
        }[choice]
        lock.observe(t, stamps)
        slew = lock.slew_s()
        assert abs(slew) <= lock.max_slew * DT + 1e-15
        assert math.isfinite(lock.tau_s) and abs(lock.tau_s) <= 0.25
        assert math.isfinite(lock.pending_s)
        t += DT + slew


def test_one_reference_person_until_their_skeletons_stop() -> None:
    """Two trackers at unrelated phases: the grid follows the first person's, not both; when
    that person is gone for REFERENCE_TIMEOUT_S, the other's."""
    lock = PhaseLock(DT)
    lags, _ = _simulate(lock, 10000, {"a": (0.01, 0.0), "b": (0.01, 0.0047)}, _transport)
    assert lock.reference == "a"
    # tau falls by a hundredth of a step per hit: the last skeletons sit on the last tau
    tail = [lag for h, lag in lags if h == "a"][-20:]
    assert np.median(tail) < lock.tau_s + 5e-5
    t = lock.reference_seen_s + REFERENCE_TIMEOUT_S - 0.01
    lock.observe(t, {"b": t - 0.001})
    assert lock.reference == "a"  # a's last skeleton is recent enough
    t += 0.02
    lock.observe(t, {"b": t - 0.001})
    assert lock.reference == "b"


def test_a_rate_that_no_phase_fits_leaves_the_grid_moving_within_bounds() -> None:
    """A 30 Hz tracker: its frames come at every phase of a 2 ms grid; the lock cannot hold,
    tau does not run away and the periods stay within the slew bound."""
    lock = PhaseLock(DT)
    _, periods = _simulate(lock, 20000, {"p": (1 / 30, 0.0)}, _transport)
    assert max(abs(p - DT) for p in periods) <= lock.max_slew * DT + 1e-12
    assert abs(np.mean(periods) - DT) < 1e-5  # the control rate, on average
    assert -DT <= lock.tau_s < 0.01


def test_a_constant_tracker_clock_offset_is_learned_as_delay() -> None:
    """A tracker whose clock runs 7.3 ms behind (its stamps look 7.3 ms older): tau takes it."""
    lock = PhaseLock(DT)
    lags, _ = _simulate(lock, 30000, {"p": (0.01, 0.0)}, lambda rng: 0.0073 + _transport(rng))
    late = np.array([lag for _, lag in lags[len(lags) // 2 :]])
    assert abs(lock.tau_s - (0.0073 + _transport_quantile(lock.quantile))) < 2e-4
    assert np.median(late) < lock.tau_s + 1e-4
