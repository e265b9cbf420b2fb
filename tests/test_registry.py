"""The registry's account of a worker's silence (:meth:`CellRegistry.silence`), on a real zenoh
router: what ``sara-app serve``'s supervisor kills a "hung" worker on. A registry whose own drain
falls behind (its thread starved: serve runs it at a lowered priority) must not read its
lateness as the worker's silence; a worker that really stops must be seen silent; the bus is
said to deliver only when the controller published after the worker's newest verdict."""

from __future__ import annotations

import time
from contextlib import closing

from waiting import wait_until as _until

from sara_app.api.registry import CellRegistry, Silence
from sara_app.bus import keys
from sara_app.bus.messages import ControllerStatusMsg, VerdictMsg
from sara_app.bus.session import Bus, Publisher, free_port


def _verdict(seq: int) -> VerdictMsg:
    return VerdictMsg(
        seq=seq, stamp_s=time.time(), cell="cell1", safety_mode="ssm", mode="intended",
        cycle_time_us=50.0,
    )  # fmt: skip


def _controller(seq: int, stamp_s: float) -> ControllerStatusMsg:
    return ControllerStatusMsg(
        seq=seq, stamp_s=stamp_s, cell="cell1", commands_received=seq, commands_lost=0,
        commands_late=0, commands_expired=0, commands_refused=0, braking_events=0,
        worker_runs=1, braking=False,
    )  # fmt: skip


def _polled(reg: CellRegistry) -> Silence | None:
    reg.poll()
    return reg.silence("cell1")


def _publish_for(pub: Publisher, seq: int, duration_s: float) -> int:
    """Verdicts at 500 Hz for ``duration_s``; the next seq."""
    t_end = time.monotonic() + duration_s
    while time.monotonic() < t_end:
        pub.put(_verdict(seq))
        seq += 1
        time.sleep(0.002)
    return seq


def test_silence_is_known_silence() -> None:
    """Verdicts keep coming while the registry is not drained for 2.5 s (a starved thread):
    the newest it holds gets old, yet the silence it knows stays at what its last complete
    drain saw, and the next drain finds the queued verdicts. Then the worker stops: silence
    grows with each drain. The bus is said to deliver only once the controller publishes after
    the newest verdict."""
    port = free_port()
    # not started: this test drains it (a started one drains on its own thread)
    with Bus.router(port), closing(CellRegistry.connect(port)) as reg, Bus.client(port) as bus:
        verdicts = bus.publisher(keys.verdict_key("cell1"))
        controller = bus.publisher(keys.controller_status_key("cell1"))
        _until(verdicts.has_subscribers)
        _until(controller.has_subscribers)
        assert reg.silence("cell1") is None  # nothing seen yet
        seq = _publish_for(verdicts, 0, 0.2)
        _until(lambda: _polled(reg))
        first = _polled(reg)
        assert first is not None and first.silent_s < 0.1 and not first.bus_since

        seq = _publish_for(verdicts, seq, 2.5)  # the registry is not drained meanwhile
        late = reg.silence("cell1")
        assert late is not None and late.age_s > 2.4  # its newest verdict is old ...
        assert late.silent_s < 0.1  # ... but it knows of no silence: it has not looked
        reg.poll()
        caught_up = reg.silence("cell1")
        assert caught_up is not None and caught_up.age_s < 0.1 and caught_up.silent_s < 0.1
        n_before = reg._cells["cell1"].verdicts
        assert n_before > 500  # the queued verdicts were taken in

        # the worker stops publishing; the registry keeps draining
        t_stop = time.monotonic()
        while time.monotonic() - t_stop < 2.5:
            reg.poll()
            time.sleep(0.02)
        stopped = reg.silence("cell1")
        assert stopped is not None and stopped.silent_s > 2.3 and not stopped.bus_since

        # a controller status stamped before the newest verdict says nothing of the bus since
        controller.put(_controller(1, stamp_s=time.time() - 10.0))
        _until(lambda: _polled(reg) and reg._cells["cell1"].controller is not None)
        old = reg.silence("cell1")
        assert old is not None and not old.bus_since
        # one published now does: the worker's silence is its own
        controller.put(_controller(2, stamp_s=time.time()))
        _until(lambda: (_polled(reg) or stopped).bus_since)
        # and a verdict again clears both
        verdicts.put(_verdict(seq))
        again = _until(lambda: (s := _polled(reg)) is not None and s.silent_s < 0.1 and s)
        assert not again.bus_since


def test_verdicts_after_gives_each_verdict_once_and_the_newest_when_far_behind() -> None:
    """What a dashboard in serve's process follows the cell on: each verdict once, in order;
    one that fell more than ``RECENT_VERDICTS`` behind gets the newest ones."""
    from sara_app.api.registry import RECENT_VERDICTS
    from sara_app.bus.codec import Decoded

    reg = CellRegistry(None)
    key = keys.parse_key(keys.verdict_key("cell1"))
    assert reg.verdicts_after("cell1", 0) == ([], 0)  # an unknown cell
    for seq in range(10):
        reg.ingest(Decoded(key, _verdict(seq), time.time()))
    got, seen = reg.verdicts_after("cell1", 0)
    assert [v.seq for v in got] == list(range(10)) and seen == 10
    assert reg.verdicts_after("cell1", seen) == ([], 10)
    for seq in range(10, 13):
        reg.ingest(Decoded(key, _verdict(seq), time.time()))
    got, seen = reg.verdicts_after("cell1", seen)
    assert [v.seq for v in got] == [10, 11, 12] and seen == 13
    for seq in range(13, 13 + 3 * RECENT_VERDICTS):
        reg.ingest(Decoded(key, _verdict(seq), time.time()))
    got, seen = reg.verdicts_after("cell1", seen)
    assert seen == 13 + 3 * RECENT_VERDICTS and len(got) == RECENT_VERDICTS
    assert [v.seq for v in got] == list(range(seen - RECENT_VERDICTS, seen))
