"""The supervisor's restarts and its hang diagnosis, on real child processes (``sleep``); the
clock is passed in, so the backoffs and ages are exact (the whole cell: test_supervision.py)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Iterator

import pytest

from sara_app.ops.supervisor import (
    BACKOFF_S,
    HUNG_AFTER_S,
    ROUTER_STOPPED_AFTER_S,
    Child,
    Supervisor,
)


def _sleeper() -> subprocess.Popen[bytes]:
    return subprocess.Popen(["sleep", "120"])


@pytest.fixture
def sup() -> Iterator[Supervisor]:
    s = Supervisor([Child("router", _sleeper), Child("worker", _sleeper)])
    s.start()
    try:
        yield s
    finally:
        s.stop(timeout_s=2.0)


def _child(s: Supervisor, name: str) -> Child:
    return next(c for c in s.children if c.name == name)


def _kill(c: Child) -> None:
    assert c.proc is not None
    c.proc.kill()
    c.proc.wait()


def test_a_silent_worker_is_killed_and_restarted(sup: Supervisor) -> None:
    worker = _child(sup, "worker")
    t0 = worker.started_s
    seen = t0 + 1.0  # a verdict through this worker and router
    assert sup.poll(t0 + 1.0 + HUNG_AFTER_S - 0.1, sup.hang_age(t0 + 2.9, seen)) == []
    events = sup.poll(t0 + 3.5, sup.hang_age(t0 + 3.5, seen))
    assert any("worker hung" in e for e in events) and not worker.alive
    assert worker.restarts == 1 and worker.due_s == pytest.approx(t0 + 3.5 + BACKOFF_S[0])


def test_no_hang_is_told_while_the_router_is_down(sup: Supervisor) -> None:
    """Verdicts reach the supervisor through the router: while it is dead or waiting for its
    restart (its backoff grows to 10 s after repeated failures) the silence is the bus's, and
    a healthy worker must not be killed for it (it was, from the third router restart on)."""
    router, worker = _child(sup, "router"), _child(sup, "worker")
    t0 = max(router.started_s, worker.started_s)
    seen = t0 + 1.0
    router.backoff_s = 8.0  # as after three quick failures
    _kill(router)
    events = sup.poll(t0 + 1.5, sup.hang_age(t0 + 1.5, seen))
    assert events == ["router exited (code -9): restart in 8.0 s"]
    for now in (t0 + 4.0, t0 + 7.0, t0 + 9.0):  # silent for up to 8 s: the router is down
        assert sup.hang_age(now, seen) is None
        assert sup.poll(now, sup.hang_age(now, seen)) == []
        assert worker.alive and worker.restarts == 0
    events = sup.poll(t0 + 9.6, sup.hang_age(t0 + 9.6, seen))
    assert events == ["router restarted (#1)"] and router.alive
    # the verdict seen before the router's restart says nothing about the worker now
    assert sup.hang_age(t0 + 12.0, seen) is None
    assert sup.poll(t0 + 12.0, None) == [] and worker.alive
    # once a verdict has come through the new router, silence is a hang again
    fresh = t0 + 12.5
    assert sup.hang_age(t0 + 13.0, fresh) == pytest.approx(0.5)
    events = sup.poll(t0 + 15.0, sup.hang_age(t0 + 15.0, fresh))
    assert any("worker hung (2.5 s without a verdict)" in e for e in events)
    assert worker.restarts == 1


def test_a_dead_child_restarts_after_a_doubling_backoff(sup: Supervisor) -> None:
    worker = _child(sup, "worker")
    now = worker.started_s
    delays = []
    for _ in range(6):
        _kill(worker)
        (event,) = sup.poll(now + 1.0, None)
        delays.append(float(event.rsplit("in ", 1)[1].split()[0]))
        assert worker.due_s is not None
        now = worker.due_s
        assert sup.poll(now, None) == [f"worker restarted (#{worker.restarts})"]
    assert delays == [0.5, 1.0, 2.0, 4.0, 8.0, BACKOFF_S[1]]


def _busy() -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def test_a_stalled_bus_does_not_kill_a_worker_that_runs() -> None:
    """A router that stops answering stays alive: the verdicts stop although the worker cycles
    (its main thread runs). Only another message through the bus since the last verdict (the
    controller's status) or a main thread that stopped running makes the silence a hang."""
    sup = Supervisor([Child("router", _sleeper), Child("worker", _busy)])
    sup.start()
    try:
        worker = _child(sup, "worker")
        t0 = worker.started_s
        seen = t0 + 1.0
        assert sup.poll(t0 + 0.5, None) == []  # serve polls from the start, 30 times a second
        for k in range(4):  # silent for 2.5 .. 4 s, the worker's main thread running
            time.sleep(0.3)
            now = t0 + 3.5 + 0.5 * k
            assert sup.poll(now, sup.hang_age(now, seen)) == [], k
            assert worker.alive and worker.restarts == 0
        # the controller's status came through the bus after the last verdict: a hang
        time.sleep(0.3)
        events = sup.poll(t0 + 6.0, sup.hang_age(t0 + 6.0, seen), bus_since=True)
        assert any("worker hung (5.0 s without a verdict)" in e for e in events)
        assert worker.restarts == 1
        # the restarted worker, stopped (SIGSTOP): its main thread no longer runs
        assert worker.due_s is not None
        sup.poll(worker.due_s, None)
        assert worker.alive and worker.proc is not None
        t1, seen = worker.started_s, worker.started_s + 0.5
        assert sup.poll(t1 + 0.2, None) == []
        time.sleep(0.3)
        assert sup.poll(t1 + 1.0, sup.hang_age(t1 + 1.0, seen)) == []
        worker.proc.send_signal(signal.SIGSTOP)
        time.sleep(0.3)
        assert sup.poll(t1 + 1.5, sup.hang_age(t1 + 1.5, seen)) == []
        time.sleep(0.3)
        assert sup.poll(t1 + 2.4, sup.hang_age(t1 + 2.4, seen)) == []  # 1.9 s silent
        time.sleep(0.3)
        events = sup.poll(t1 + 4.0, sup.hang_age(t1 + 4.0, seen))
        assert any("worker hung (3.5 s without a verdict)" in e for e in events)
        assert worker.restarts == 2
    finally:
        sup.stop(timeout_s=2.0)


def test_a_stopped_router_is_restarted_and_a_short_stop_is_left_alone(sup: Supervisor) -> None:
    """A router stopped (SIGSTOP) resumes by itself after a short stop (``soak --chaos``: up to
    2 s); stopped for ``ROUTER_STOPPED_AFTER_S`` it is killed and restarted (it never was: a
    stopped router left every cell offline until someone sent it SIGCONT)."""
    router, worker = _child(sup, "router"), _child(sup, "worker")
    assert router.proc is not None
    t0 = router.started_s
    router.proc.send_signal(signal.SIGSTOP)
    time.sleep(0.2)
    assert sup.poll(t0 + 1.0, None) == []
    assert sup.poll(t0 + 1.0 + ROUTER_STOPPED_AFTER_S - 0.1, None) == []
    router.proc.send_signal(signal.SIGCONT)  # a short stop: it runs on, nothing restarted
    time.sleep(0.2)
    assert sup.poll(t0 + 7.0, None) == [] and router.stopped_s is None
    router.proc.send_signal(signal.SIGSTOP)
    time.sleep(0.2)
    assert sup.poll(t0 + 8.0, None) == []
    events = sup.poll(t0 + 8.0 + ROUTER_STOPPED_AFTER_S, None)
    assert events[0] == f"router stopped for {ROUTER_STOPPED_AFTER_S:.1f} s: killed"
    assert events[1].startswith("router exited (code -9): restart in 0.5 s")
    assert not router.alive and router.restarts == 1
    assert router.due_s is not None and sup.poll(router.due_s, None) == ["router restarted (#1)"]
    assert router.alive and router.stopped_s is None
    assert worker.alive and worker.restarts == 0  # the worker was never the cause
