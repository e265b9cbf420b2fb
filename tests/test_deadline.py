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
    assert fired == []
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
    last push."""
    fired: list[tuple[float, bool]] = []
    deadline.arm(0.02)
    t = _waiter(deadline, fired)
    t_end = time.monotonic() + 0.3
    while time.monotonic() < t_end:
        deadline.arm(0.02)
        time.sleep(0.005)
    last = time.monotonic()
    deadline.arm(0.02)
    assert fired == []
    while not fired and time.monotonic() - last < 5:
        time.sleep(0.002)
    assert fired[0][1] and fired[0][0] - last >= 0.02 - 1e-3
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
