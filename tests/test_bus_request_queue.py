"""Request queues (sara_app.bus.request_queue) on real zenoh sessions on 127.0.0.1: requests come
out in order and a drain takes at most what it asks for; whatever a full queue loses is counted
as ``queue_full``, never dropped silently, and what waits is bounded in bytes as well as in
count (a payload over the contract's largest is ``too_large`` at once); and in a process
whose zenoh I/O runs on one thread a flooded queue that nobody drains holds up no other
message, where a FIFO subscription holds up all of them (a subprocess: the layout is read once
per process)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time

import pytest

from sara_app.bus import keys
from sara_app.bus.codec import MAX_PAYLOAD_BYTES, REASONS, Decoder
from sara_app.bus.io_threads import ZENOH_RUNTIME_ENV
from sara_app.bus.messages import RetireMsg
from sara_app.bus.request_queue import QUEUE_FULL, RequestQueue, requests
from sara_app.bus.session import Bus, BusError, Publisher, free_port

CELL = "cell1"


def _send(pub: Publisher, first: int, n: int) -> None:
    for i in range(first, first + n):
        pub.put(RetireMsg(seq=pub.next_seq(), stamp_s=time.time(), request_id=f"r{i}",
                          human_id="h1", user="op"))  # fmt: skip


def _arrived(q: RequestQueue, n: int, timeout_s: float = 10.0) -> None:
    """Wait until ``n`` requests wait in the queue (taken into it, none decoded)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        q.drain(0)
        if q.waiting() >= n:
            return
        time.sleep(0.01)
    raise AssertionError(f"{n} requests did not arrive in {timeout_s} s")


def test_requests_come_out_in_order_at_most_max_n_a_drain() -> None:
    with Bus.router(free_port()) as bus:
        q = requests(bus, keys.retire_key(CELL), capacity=64)
        pub = bus.publisher(keys.retire_key(CELL))
        _send(pub, 0, 10)
        _arrived(q, 10)
        first = [d.msg.request_id for d in q.drain(3).messages]
        assert first == ["r0", "r1", "r2"] and q.waiting() == 7
        _send(pub, 10, 5)
        _arrived(q, 5)
        rest = [d.msg.request_id for d in q.drain().messages]
        assert rest == [f"r{i}" for i in range(3, 15)]  # the waiting first, then the new
        assert QUEUE_FULL not in q.decoder.counts and q.waiting() == 0
        assert QUEUE_FULL in REASONS  # a contract reason (CONTRACT.md's table lists them)


def test_a_request_queue_is_never_waited_on_nor_taken_newest_only() -> None:
    """The subscription's other ways out would pass the backlog (out of order) or count
    requests as superseded: both refuse, naming the way in order, and the requests wait."""
    with Bus.router(free_port()) as bus:
        q = requests(bus, keys.retire_key(CELL), capacity=64)
        _send(bus.publisher(keys.retire_key(CELL)), 0, 3)
        _arrived(q, 3)
        for way in (q.receive, q.drain_latest):
            with pytest.raises(BusError, match=r"drain\(max_n\)"):
                way()
        assert [d.msg.request_id for d in q.drain().messages] == ["r0", "r1", "r2"]


@pytest.mark.parametrize("burst", [16, 24, 40, 300])
def test_what_a_full_queue_loses_is_counted(burst: int) -> None:
    """A burst into a queue of 16 (its ring 32) that is drained two at a time: what comes out
    is in order, and every request that does not is counted (the ring's overrun at least
    once)."""
    with Bus.router(free_port()) as bus:
        q = requests(bus, keys.retire_key(CELL), Decoder(), capacity=16)
        pub = bus.publisher(keys.retire_key(CELL))
        _send(pub, 0, burst)
        time.sleep(0.5)  # the burst delivered into the ring (it never blocks), none taken
        taken: list[int] = []
        for _ in range(20):
            taken += [int(d.msg.request_id[1:]) for d in q.drain(2).messages]
        assert taken == sorted(taken) and len(set(taken)) == len(taken)
        lost = q.decoder.counts.get(QUEUE_FULL, 0)
        if burst <= 16:
            assert taken == list(range(burst)) and lost == 0
        else:  # the 16 oldest it holds; every other one counted, the ring's overrun once
            assert len(taken) == 16 and taken[-1] - taken[0] == 15, taken
            assert lost == burst - 16 if burst <= 32 else 16 + 1 <= lost <= burst - 16, lost


def test_what_waits_is_bounded_in_bytes_and_an_oversized_request_is_refused_at_once() -> None:
    """Large requests (edits may be megabytes) fill a queue of 64 by bytes long before its
    count: the backlog keeps the oldest that fit in its 1 MB, the newer ones are counted
    ``queue_full`` even where a smaller one would fit (the newest go, in order), a payload
    over 4 MiB is ``too_large`` without waiting, and room taken out frees bytes again."""
    mb = 1_000_000
    with Bus.router(free_port()) as bus:
        q = requests(bus, keys.retire_key(CELL), Decoder(), capacity=64, max_bytes=mb)
        raw = bus.session.declare_publisher(keys.retire_key(CELL))
        for size in (300_000, 300_000, 300_000, 300_000, 10, MAX_PAYLOAD_BYTES + 1):
            raw.put(b"x" * size)
        _arrived(q, 3)
        deadline = time.monotonic() + 10.0
        counts = q.decoder.counts
        while counts.get(QUEUE_FULL, 0) + counts.get("too_large", 0) < 3:
            assert time.monotonic() < deadline, counts
            q.drain(0)
            time.sleep(0.01)
        assert q.waiting() == 3  # 900 kB: the fourth would pass 1 MB
        assert counts[QUEUE_FULL] == 2 and counts["too_large"] == 1, counts
        q.drain(2)  # two taken (refused by the decoder: not messages), 600 kB free again
        raw.put(b"x" * 600_000)
        _arrived(q, 2)
        assert q.waiting() == 2 and counts[QUEUE_FULL] == 2


# A process on one I/O thread: a key flooded and never drained (a request queue or a FIFO
# subscription of 8), then one message on another key; prints when that one arrived (or null),
# then waits to be killed.
_PROBE = textwrap.dedent(
    """
    import json, sys, time
    import zenoh
    from sara_app.bus import io_threads
    from sara_app.bus.request_queue import requests
    from sara_app.bus.session import Bus

    io_threads.use_one_io_thread()
    with Bus.client(int(sys.argv[1])) as bus:
        if sys.argv[2] == "requests":
            flooded = requests(bus, "sara/probe/requests", capacity=8)
        else:  # a FIFO declared on the session itself: the project refuses one here
            flooded = bus.session.declare_subscriber("sara/probe/requests",
                                                     zenoh.handlers.FifoChannel(8))
        other = bus.subscribe("sara/probe/other")
        print("ready", flush=True)
        sys.stdin.readline()  # the flood, then the other key's message, are sent
        t0 = time.monotonic()
        seen = None
        while time.monotonic() - t0 < 3.0 and seen is None:
            if other._samples(None):
                seen = time.monotonic() - t0
            time.sleep(0.01)
        # said before the session closes: with the FIFO full its close waits on that thread too
        print(json.dumps({"other_after_s": seen}), flush=True)
        time.sleep(60)
    """
)


def _flood_then_other(kind: str) -> float | None:
    port = free_port()
    env = {k: v for k, v in os.environ.items() if k != ZENOH_RUNTIME_ENV}
    with Bus.router(port) as router:
        pipes = {"stdin": subprocess.PIPE, "stdout": subprocess.PIPE, "text": True}
        proc = subprocess.Popen([sys.executable, "-c", _PROBE, str(port), kind], env=env, **pipes)
        try:
            assert proc.stdout is not None and proc.stdin is not None
            assert proc.stdout.readline().strip() == "ready"
            flood = router.session.declare_publisher("sara/probe/requests")
            other = router.session.declare_publisher("sara/probe/other")
            time.sleep(0.5)  # both subscriptions known to the router
            for _ in range(2000):
                flood.put(b"x" * 100)
            other.put(b"here")
            proc.stdin.write("go\n")
            proc.stdin.flush()
            out = proc.stdout.readline()  # within 3 s; the process is then killed
        finally:
            proc.kill()
            proc.wait()
    return json.loads(out)["other_after_s"]  # type: ignore[no-any-return]


@pytest.mark.skipif(sys.platform != "linux", reason="zenoh's runtime layout as on the cell")
def test_a_flooded_request_queue_holds_up_nothing_on_one_io_thread() -> None:
    assert _flood_then_other("requests") is not None  # arrived while the flood sat undrained
    assert _flood_then_other("fifo") is None  # the FIFO's back-pressure held the only thread
