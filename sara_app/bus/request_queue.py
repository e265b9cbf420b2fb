"""Requests on the bus (scenario edits, retirements, re-plans), queued without ever blocking
zenoh's thread, and counted where they are lost.

A FIFO subscription holds the thread that delivers into its full queue until the loop drains
it (back-pressure): on zenoh's default threads that is every message of the process's link to
the router (a flood of retirements held up the worker's robot states, 2026-12-04), and on one
I/O thread (:mod:`~sara_app.bus.io_threads`) every message of the process, commands included.
A :class:`RequestQueue` takes its samples from a ring instead (zenoh's thread never waits) and
moves all of them, undecoded, into its own backlog at each drain; the loop then decodes and
handles a bounded number per cycle, in arrival order.

What does not fit is counted in the decoder, never dropped silently:
- a request over the contract's largest payload (``MAX_PAYLOAD_BYTES``) is ``too_large`` at
  once: the decoder would refuse it, and held undecoded it only took memory;
- the backlog holds at most ``capacity`` requests and ``max_bytes`` of payload; a request
  that finds it full is refused with every newer one of the same drain (the newest go, as a
  full FIFO would refuse them) and counted as ``queue_full``, exactly. The byte bound, with
  the worker decoding one edit a cycle (:mod:`sara_app.runtime.edits`), took its peak memory
  under 300 edits of 2 MB sent at once from 700-840 MB to 340-520 MB
  (docs/measurements/2026-12-05-edit-flood-memory.md);
- the ring holds twice that; a drain that finds it full may have lost its oldest requests
  to newer ones (a ring cannot say how many): counted once, a lower bound (and once too when
  the ring had just filled, lost nothing: it cannot tell).
A lost request is never answered: its sender's wait for the answer ends without one (the API
says so), and nothing it asked for happens.
"""

from __future__ import annotations

import logging
from collections import deque
from typing import Any

from sara_app.bus.codec import MAX_PAYLOAD_BYTES, Decoder
from sara_app.bus.process import SummarisedWarning
from sara_app.bus.session import Bus, BusError, Drained, Subscription

log = logging.getLogger("sara_app.bus")

REQUEST_CAPACITY = 256
"""Requests of one key waiting for the loop, at most (the ring zenoh fills holds twice this):
far above an operator's pace (the worker takes 2-8 a cycle, 1 000-4 000 a second at 500 Hz)."""

REQUEST_BYTES = 16 * 1024 * 1024
"""Payload bytes of one key's requests waiting for the loop, at most: four requests of the
largest payload the contract takes (4 MiB), hundreds of an operator's usual size."""

QUEUE_FULL = "queue_full"
"""The drop reason of a request lost to a full queue (the contract's ``queue_full``)."""


class RequestQueue(Subscription):
    """Requests on ``key_expr``: a ring of ``2 * capacity`` samples that zenoh fills, and a
    backlog of at most ``capacity`` requests and ``max_bytes`` of payload that :meth:`drain`
    fills from it (module doc). ``drain(max_n)`` decodes at most ``max_n`` of the oldest
    requests; the others wait for the next drain."""

    def __init__(
        self,
        session: Any,
        key_expr: str,
        decoder: Decoder,
        capacity: int,
        max_bytes: int = REQUEST_BYTES,
    ) -> None:
        super().__init__(session, key_expr, decoder, 2 * int(capacity), fifo=False)
        self.capacity = int(capacity)
        self.max_bytes = int(max_bytes)
        self._backlog: deque[tuple[str, bytes]] = deque()
        self._bytes = 0  # the backlog's payload bytes
        self._lost_log = SummarisedWarning(log, f"requests on {key_expr} lost to a full queue")

    def drain(self, max_n: int | None = None) -> Drained:
        """Move every queued sample into the backlog (counting what does not fit), then decode
        the ``max_n`` oldest (all: None) without blocking."""
        arrived = self._samples(None)
        # the ring found full may have dropped older samples for these: one at least
        lost = int(len(arrived) >= 2 * self.capacity)
        too_large = full = 0
        for key, payload in arrived:
            size = len(payload)
            if size > MAX_PAYLOAD_BYTES:
                too_large += 1
            elif full or len(self._backlog) >= self.capacity or self._bytes + size > self.max_bytes:
                full += 1  # this one and every newer one: a full FIFO refuses the newest
            else:
                self._backlog.append((key, payload))
                self._bytes += size
        lost += full
        if too_large:
            self.decoder.count("too_large", too_large)
        if lost:
            self.decoder.count(QUEUE_FULL, lost)
        if lost or too_large:
            self._lost_log(
                f"{lost} at once for room, {too_large} over {MAX_PAYLOAD_BYTES} bytes; "
                f"{len(self._backlog)} waiting ({self._bytes} bytes)"
            )
        n = len(self._backlog) if max_n is None else min(max_n, len(self._backlog))
        taken = [self._backlog.popleft() for _ in range(n)]
        self._bytes -= sum(len(p) for _, p in taken)
        return self._decode(taken)

    def waiting(self) -> int:
        """Requests in the backlog (not counting those still in the ring)."""
        return len(self._backlog)

    def receive(self) -> Drained | None:
        """Not for requests: a wait on the ring would pass the backlog (out of order)."""
        raise BusError(
            f"requests on {self.key_expr} are taken in order with drain(max_n), not receive(): "
            "a subscription (Bus.subscribe) is the one to wait on"
        )

    def drain_latest(self) -> Drained:
        """Not for requests: each one is answered, none supersedes another."""
        raise BusError(
            f"requests on {self.key_expr} are each taken with drain(max_n), not "
            "drain_latest(): none of them supersedes another"
        )


def requests(
    bus: Bus,
    key_expr: str,
    decoder: Decoder | None = None,
    capacity: int = REQUEST_CAPACITY,
    max_bytes: int = REQUEST_BYTES,
) -> RequestQueue:
    """A :class:`RequestQueue` on ``key_expr`` in ``bus``'s session, closed with it; share
    ``decoder`` to pool counters."""
    queue = RequestQueue(bus.session, key_expr, decoder or Decoder(), capacity, max_bytes)
    bus.own(queue)
    return queue
