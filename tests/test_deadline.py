"""The controller's deadline (sara_app.peers.deadline), on the kernel timer and on its
condition-variable fallback: it fires once after its delay, re-arming pushes it back without a
firing in between, and closing ends a wait."""

from __future__ import annotations

import threading
import time

import pytest

from sara_app.peers.deadline import Deadline


@pytest.fixture(params=[True, False], ids=["timerfd", "fallback"])
def deadline(request: pytest.FixtureRequest):
    d = Deadline(use_timerfd=request.param)
    assert d.kernel_timer == request.param or not request.param  # a timerfd where there is one
    yield d
    d.close()
    d.release()


def _waiter(d: Deadline, fired: list[tuple[float, bool]]) -> threading.Thread:
    def run() -> None:
        while True:
            ok = d.wait()
            fired.append((time.monotonic(), ok))
            if not ok:
                return

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_it_fires_after_its_delay_and_not_before(deadline: Deadline) -> None:
    fired: list[tuple[float, bool]] = []
    t0 = time.monotonic()
    deadline.arm(0.08)
    t = _waiter(deadline, fired)
    time.sleep(0.04)
    seen, at = list(fired), time.monotonic()
    if at < t0 + 0.08:  # a loaded machine may oversleep past the delay: then firing is right
        assert seen == []
    while not fired and time.monotonic() - t0 < 5:
        time.sleep(0.002)
    assert fired[0][1] and fired[0][0] - t0 >= 0.08 - 1e-3
    time.sleep(0.1)
    assert len(fired) == 1  # once: not re-armed
    deadline.close()
    t.join(2)
    assert not t.is_alive() and fired[-1][1] is False


def test_pushing_it_back_delays_it_without_a_firing_between(deadline: Deadline) -> None:
    """Re-armed every 5 ms to 20 ms ahead for 0.3 s, it never fires; it fires 20 ms after the
    last push. (A loaded machine may oversleep a push past 20 ms: a firing then is right, so
    each firing is checked against the pushes done before it, not against none at all.)"""
    fired: list[tuple[float, bool]] = []
    arms: list[tuple[float, float]] = []  # (just before arm(), just after it)

    def arm() -> None:
        before = time.monotonic()
        deadline.arm(0.02)
        arms.append((before, time.monotonic()))

    arm()
    t = _waiter(deadline, fired)
    t_end = time.monotonic() + 0.3
    while time.monotonic() < t_end:
        arm()
        time.sleep(0.005)
    last = time.monotonic()
    arm()
    while not any(f >= arms[-1][1] for f, _ in fired):  # the last push's own firing
        assert time.monotonic() - last < 5, "it never fired after the last push"
        time.sleep(0.002)
    for f, ok in fired:  # a push done before a firing had its 20 ms at least
        assert ok and f >= max(b for b, a in arms if a <= f) + 0.02 - 1e-3, (f, arms[-3:])
    # the longest it was left armed: from one push's start to the end of the next
    left_s = max(a1 - b0 for (b0, _), (_, a1) in zip(arms, arms[1:], strict=False))
    if left_s < 0.02:  # never left alone for its delay: never fired before the last
        assert all(f >= last for f, _ in fired), (fired, left_s)
    deadline.close()
    t.join(2)
    assert not t.is_alive()


def test_closing_ends_a_wait_and_every_later_one(deadline: Deadline) -> None:
    fired: list[tuple[float, bool]] = []
    deadline.arm(60.0)
    t = _waiter(deadline, fired)
    time.sleep(0.05)
    deadline.close()
    t.join(2)
    assert not t.is_alive() and [ok for _, ok in fired] == [False]
    assert deadline.wait() is False
