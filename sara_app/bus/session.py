"""Zenoh sessions on loopback, subscribers drained by the caller's loop, publishers.

- ``router_config(port)``: the embedded hub, a router listening on ``tcp/127.0.0.1:<port>``;
  ``client_config(port)``: a process that connects to it. Multicast and gossip scouting are off,
  listeners are refused on non-loopback hosts. ``free_port()`` picks an unused TCP port.
- ``Bus(config)`` (or ``Bus.router(port)`` / ``Bus.client(port)``) owns one zenoh session and
  everything declared on it; ``close()`` (or ``with Bus...:``) undeclares all and closes it, so
  the process can exit. Opening raises ``BusError`` when the session cannot be opened.
- ``bus.subscribe(key_expr)`` -> ``Subscription``: samples queue in a zenoh RingChannel (drops
  the oldest when full: a sensor stream wants the newest; ``fifo=True`` for a FifoChannel, which
  back-pressures instead). ``drain()`` never blocks: it returns ``Drained(messages, rejected)``,
  the decoded messages and the number rejected during this drain; per-reason counters live in
  the (shareable) ``Decoder``. Requests (edits, retirements, re-plans) queue in order
  without blocking zenoh's thread: :func:`sara_app.bus.request_queue.requests`.
- ``bus.publisher(key)`` -> ``Publisher``: ``put(msg)`` encodes and sends, never raises (a failure
  is counted in ``failed`` and logged) and returns whether it was sent; ``next_seq()`` numbers
  messages 0, 1, 2, ...; ``has_subscribers()`` tells whether anyone listens. Each key's
  messages travel at its lane's priority (``priority_of``): the robot's ahead of everything,
  then requests and answers, the evidence of people, reports, display.

Zenoh callbacks run on zenoh threads and need the GIL; the channel handlers here keep all
decoding on the caller's thread.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import socket
import threading
from typing import Any, NamedTuple

import zenoh

from sara_app.bus import io_threads, keys
from sara_app.bus.codec import Decoded, Decoder
from sara_app.bus.compact import KIND_CODES, CommandArrays, encode_compact
from sara_app.bus.messages import encode
from sara_app.errors import ParameterError, SaraError

LOOPBACK = "127.0.0.1"
DEFAULT_PORT = 7447
ROUTER_MAX_MESSAGE_BYTES = 8 * 1024 * 1024
"""The router drops any message larger than this (zenoh's ``transport.link.rx.max_message_size``)
before it is forwarded: twice the decoders' limit, so a too-large-but-plausible message is still
counted as ``too_large`` by the worker, and a huge put never reaches (or stalls) anyone."""
_NO_SCOUTING = {"multicast": {"enabled": False}, "gossip": {"enabled": False}}
NO_SHARED_MEMORY = {"enabled": False}
"""zenoh's shared-memory transport (``transport.shared_memory``), off in every session here.
Its default (on, ``mode: lazy``) sets up a 16 MB pool, mlocked, and its watchdogs in the
thread of the first put or receive of a message above 3 kB: in a live worker that was the first
display message with a person in it, and the cycle took 6-14 ms instead of 0.3 (page faults and
``mlock``, seen with ``perf``), long enough for the controller's command to expire. The cell's
messages are small (commands 0.5 kB, skeletons 0.25 kB a person), so copying them costs less."""

log = logging.getLogger("sara_app.bus")


class BusError(SaraError):
    """A zenoh session could not be opened or used."""


class Drained(NamedTuple):
    """Decoded messages, the number rejected and the keys of the rejected ones (in order)."""

    messages: list[Decoded]
    rejected: int
    refused_keys: list[str] = []


def free_port(host: str = LOOPBACK) -> int:
    """An unused TCP port on ``host`` (free when checked; zenoh endpoints cannot bind port 0)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def endpoint(port: int, host: str = LOOPBACK, secured: bool = False) -> str:
    """``tcp/<host>:<port>``. ``host`` must be a loopback address unless the session is
    ``secured`` (authenticated, with the router's access control): a bus reachable from other
    machines is never open (ParameterError otherwise)."""
    if host != "localhost":
        try:
            address = ipaddress.ip_address(host)
        except ValueError:
            raise ParameterError(
                f"bus host {host!r} is not an IP address; use 127.0.0.1 (loopback), or the "
                "router machine's address with credentials"
            ) from None
        if not address.is_loopback and not secured:
            raise ParameterError(
                f"bus host {host!r} is not a loopback address; use 127.0.0.1, or credentials "
                "and access control for a bus on several machines (docs/deployment.md)"
            )
    if not isinstance(port, int) or not 0 < port < 65536:
        raise ParameterError(f"bus port {port!r} is not in 1..65535")
    return f"tcp/{host}:{port}"


def router_config(
    port: int = DEFAULT_PORT, host: str = LOOPBACK, access: dict[str, Any] | None = None
) -> zenoh.Config:
    """A router session listening on ``tcp/<host>:<port>`` (loopback by default), no scouting;
    ``access``: authentication and access control (:func:`sara_app.bus.access.router_access`)."""
    return zenoh.Config.from_json5(json.dumps(router_config_dict(port, host, access)))


def router_config_dict(
    port: int = DEFAULT_PORT, host: str = LOOPBACK, access: dict[str, Any] | None = None
) -> dict[str, Any]:
    """:func:`router_config` as a plain dict: also a stand-alone ``zenohd`` configuration file
    (JSON is JSON5) for a router on a machine of its own (``python -m sara_app.bus.router
    --print-config``)."""
    transport: dict[str, Any] = {
        "link": {
            "rx": {"max_message_size": ROUTER_MAX_MESSAGE_BYTES},
            "tx": {"queue": tx_queue_config()},
        },
        "shared_memory": NO_SHARED_MEMORY,
    }
    cfg: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": [endpoint(port, host, secured=access is not None)]},
        "scouting": _NO_SCOUTING,
        "transport": transport,
    }
    if access is not None:
        transport.update(access["transport"])
        cfg["access_control"] = access["access_control"]
    return cfg


def client_config(
    port: int = DEFAULT_PORT,
    host: str = LOOPBACK,
    timeout_ms: int = 5000,
    auth: dict[str, Any] | None = None,
    timestamping: bool = False,
) -> zenoh.Config:
    """A client session that connects to ``tcp/<host>:<port>``, giving up after ``timeout_ms``;
    ``auth``: its credentials (:func:`sara_app.bus.access.client_auth`); ``timestamping``:
    each message it puts carries zenoh's timestamp of its publication (this machine's clock;
    without it the router stamps the message's arrival)."""
    connect = {"endpoints": [endpoint(port, host, secured=auth is not None)],
               "timeout_ms": int(timeout_ms)}  # fmt: skip
    transport: dict[str, Any] = {
        "shared_memory": NO_SHARED_MEMORY,
        "link": {"tx": {"queue": tx_queue_config()}},
        **(auth or {}),
    }
    cfg: dict[str, Any] = {
        "mode": "client",
        "connect": connect,
        "scouting": _NO_SCOUTING,
        "transport": transport,
    }
    if timestamping:
        cfg["timestamping"] = {"enabled": True}
    return zenoh.Config.from_json5(json.dumps(cfg))


class Subscription:
    """Samples of one key expression, queued by zenoh and decoded by ``drain()`` (never blocks)
    or :meth:`receive` (sleeps in zenoh's channel until a sample comes: for a loop that mostly
    waits, such as a robot controller; the waiting thread is woken by zenoh's receiving thread
    directly, with no Python thread in between)."""

    def __init__(
        self, session: zenoh.Session, key_expr: str, decoder: Decoder, capacity: int, fifo: bool
    ) -> None:
        self.key_expr = key_expr
        self.decoder = decoder
        channel = zenoh.handlers.FifoChannel if fifo else zenoh.handlers.RingChannel
        self._sub: Any = session.declare_subscriber(key_expr, channel(int(capacity)))
        # the handler apart from the subscriber: a thread blocked in its recv() does not hold
        # the subscriber, which close() can then undeclare (the recv then ends with an error)
        self._handler: Any = self._sub.handler
        self._closing = threading.Lock()

    def receive(self) -> Drained | None:
        """Sleep until a sample is queued, then decode it and every other one queued; None once
        the subscription is closed (also while it sleeps). One thread at a time."""
        handler = self._handler
        if handler is None:
            return None
        try:
            first = handler.recv()
        except zenoh.ZError:  # closed
            return None
        return self._decode([(str(first.key_expr), first.payload.to_bytes()), *self._samples(None)])

    def _samples(self, max_n: int | None) -> list[tuple[str, bytes]]:
        """Up to ``max_n`` queued samples as ``(key, payload)``, without blocking."""
        out: list[tuple[str, bytes]] = []
        handler = self._handler
        if handler is None:
            return out
        while max_n is None or len(out) < max_n:
            try:
                sample = handler.try_recv()
            except zenoh.ZError as e:  # closed underneath us: nothing more to read
                log.warning("bus: subscription %s: %s", self.key_expr, e)
                break
            if sample is None:
                break
            out.append((str(sample.key_expr), sample.payload.to_bytes()))
        return out

    def _decode(self, samples: list[tuple[str, bytes]]) -> Drained:
        out: list[Decoded] = []
        refused: list[str] = []
        before = self.decoder.rejected
        for key, payload in samples:
            d = self.decoder.decode(key, payload)
            if d is None:
                refused.append(key)
            else:
                out.append(d)
        return Drained(out, self.decoder.rejected - before, refused)

    def drain(self, max_n: int | None = None) -> Drained:
        """Decode every queued sample (at most ``max_n``) without blocking."""
        return self._decode(self._samples(max_n))

    def drain_latest(self) -> Drained:
        """Decode only the newest queued sample of each key; the older ones are counted as
        ``superseded`` in the decoder (a newer measurement of the same publisher replaces them:
        under a flood on one key this keeps the work per drain bounded by the number of keys)."""
        latest: dict[str, bytes] = {}
        n = 0
        for key, payload in self._samples(None):
            latest.pop(key, None)  # re-insert: keys ordered by their newest sample
            latest[key] = payload
            n += 1
        if n > len(latest):
            self.decoder.count("superseded", n - len(latest))
        return self._decode(list(latest.items()))

    def close(self) -> None:
        """Undeclare (idempotent; safe from another thread: the subscriber is taken first, so a
        second close while the first undeclares finds nothing to do)."""
        with self._closing:
            sub, self._sub, self._handler = self._sub, None, None
        if sub is not None:
            try:
                sub.undeclare()
            except zenoh.ZError:
                pass


ROBOT_ENCODINGS = ("json", "compact")
"""How a session publishes on the robot keys (``robot/state``, ``robot/command``): JSON, or the
compact records of :mod:`sara_app.bus.compact`. Decoders accept both."""


PRIORITY_OF_LANE: dict[str, zenoh.Priority] = {
    "control": zenoh.Priority.REAL_TIME,
    "request": zenoh.Priority.INTERACTIVE_HIGH,
    "evidence": zenoh.Priority.DATA_HIGH,
    "report": zenoh.Priority.DATA,
    "display": zenoh.Priority.DATA_LOW,
}
"""The zenoh priority of each lane (:data:`sara_app.bus.keys.LANE_OF`)."""

TX_QUEUE_BATCHES = 16
"""Batches each priority's transmit queue holds (zenoh's ``transport.link.tx.queue.size``; its
default 2, its most 16), in every session and on the router's links. A put into a full queue
waits 1 ms, then drops: with 2, a transmit thread that waits a few ms for a CPU lost a cycle's
verdict and status (3-9 % of them beside 4 busy processes, ``sara-app bench --lanes``), now and
then an answer to an edit; with 16 they arrive late instead (none lost in the same runs). A
command, too, arrives late rather than not at all; a command later than its validity is
discarded by the controller, and the commands lost or late together stayed about as many
(docs/performance.md, "Deeper transmit queues"). Allocated lazily: memory only while a backlog
lasts, at most 1 MB per priority and link (16 batches of 64 kB)."""

_TX_QUEUES = ("control", "real_time", "interactive_high", "interactive_low", "data_high", "data",
              "data_low", "background")  # fmt: skip
"""zenoh's transmit queues, one per priority, as its config names them."""


def tx_queue_config() -> dict[str, Any]:
    """``transport.link.tx.queue`` of every session here: :data:`TX_QUEUE_BATCHES` per
    priority."""
    return {"size": dict.fromkeys(_TX_QUEUES, TX_QUEUE_BATCHES)}


def priority_of(key_expr: str) -> zenoh.Priority:
    """The zenoh priority a message on ``key_expr`` is published at: its kind's lane; a key
    outside the contract travels as a report (zenoh's default priority)."""
    kind = _kind(key_expr)
    return PRIORITY_OF_LANE[keys.LANE_OF[kind] if kind is not None else "report"]


class Publisher:
    """Publishes validated messages on one key, in its kind's lane (:func:`priority_of`);
    numbers them with ``next_seq()``; ``compact``: as compact records (robot keys only)."""

    def __init__(
        self, session: zenoh.Session, key_expr: str, express: bool, compact: bool = False
    ) -> None:
        self.key_expr = key_expr
        self._encode = encode_compact if compact else _encode_json
        self.failed = 0
        self._seq = -1
        self._pub: Any = session.declare_publisher(
            key_expr,
            congestion_control=zenoh.CongestionControl.DROP,
            priority=priority_of(key_expr),
            express=express,
        )

    def next_seq(self) -> int:
        self._seq += 1
        return self._seq

    def continue_after(self, seq: int) -> None:
        """Number the next message after ``seq`` (another publisher of this process used the
        key before: its subscribers would refuse a restart from 0 as out of order)."""
        self._seq = max(self._seq, int(seq))

    def has_subscribers(self) -> bool:
        """Whether a matching subscriber is known (e.g. to wait before a first message)."""
        try:
            return self._pub is not None and bool(self._pub.matching_status.matching)
        except zenoh.ZError:
            return False

    def put(self, msg: Any) -> bool:
        """Encode and send ``msg``; False (counted, logged) when it could not be sent."""
        try:
            if self._pub is None:
                raise BusError("publisher is closed")
            self._pub.put(self._encode(msg))
            return True
        except Exception as e:  # noqa: BLE001 - publishing must never end the caller's loop
            self.failed += 1
            if self.failed & (self.failed - 1) == 0:
                log.warning("bus: put #%d on %s failed: %r", self.failed, self.key_expr, e)
            return False

    def close(self) -> None:
        if self._pub is not None:
            try:
                self._pub.undeclare()
            except zenoh.ZError:
                pass
            self._pub = None


def _encode_json(msg: Any) -> bytes:
    """A message's JSON; a worker's :class:`~sara_app.bus.compact.CommandArrays` through its
    validated message."""
    return encode(msg.message() if isinstance(msg, CommandArrays) else msg)


def _kind(key_expr: str) -> str | None:
    try:
        return keys.parse_key(key_expr).kind
    except SaraError:
        return None


class Bus:
    """One zenoh session and what was declared on it; close it to let the process exit."""

    def __init__(self, config: zenoh.Config, robot_encoding: str = "json") -> None:
        if robot_encoding not in ROBOT_ENCODINGS:
            raise ParameterError(
                f"robot encoding {robot_encoding!r}; valid: {', '.join(ROBOT_ENCODINGS)}"
            )
        self.robot_encoding = robot_encoding
        """How :meth:`publisher` encodes robot states and commands (:data:`ROBOT_ENCODINGS`)."""
        io_threads.note_session()
        try:
            self.session = zenoh.open(config)
        except zenoh.ZError as e:
            raise BusError(f"cannot open the zenoh session: {e}") from None
        self._owned: list[Subscription | Publisher] = []

    @classmethod
    def router(
        cls, port: int = DEFAULT_PORT, host: str = LOOPBACK, access: dict[str, Any] | None = None
    ) -> Bus:
        return cls(router_config(port, host, access))

    @classmethod
    def client(
        cls,
        port: int = DEFAULT_PORT,
        host: str = LOOPBACK,
        timeout_ms: int = 5000,
        auth: dict[str, Any] | None = None,
        robot_encoding: str = "json",
        timestamping: bool = False,
    ) -> Bus:
        return cls(client_config(port, host, timeout_ms, auth, timestamping), robot_encoding)

    def subscribe(
        self,
        key_expr: str,
        decoder: Decoder | None = None,
        capacity: int = 256,
        fifo: bool = False,
    ) -> Subscription:
        """Subscribe to ``key_expr`` (wildcards allowed); share ``decoder`` to pool counters.
        ``fifo``: back-pressure instead of dropping the oldest; refused in a process whose I/O
        runs on one thread (:func:`~sara_app.bus.io_threads.refuse_fifo`)."""
        if fifo:
            io_threads.refuse_fifo(key_expr)
        sub = Subscription(self.session, key_expr, decoder or Decoder(), capacity, fifo)
        self._owned.append(sub)
        return sub

    def own(self, item: Subscription | Publisher) -> None:
        """Close ``item`` with this session (one declared on it elsewhere, e.g. a
        :class:`~sara_app.bus.request_queue.RequestQueue`)."""
        self._owned.append(item)

    def publisher(self, key_expr: str) -> Publisher:
        """A publisher on one concrete key: sent at once (``express``) unless its kind is one of
        :data:`~sara_app.bus.keys.BATCHED_KINDS`; on a robot key, in the session's
        :attr:`robot_encoding`."""
        kind = _kind(key_expr)
        compact = self.robot_encoding == "compact" and kind in KIND_CODES
        pub = Publisher(self.session, key_expr, kind not in keys.BATCHED_KINDS, compact)
        self._owned.append(pub)
        return pub

    def close(self) -> None:
        """Undeclare everything and close the session (idempotent)."""
        for item in self._owned:
            item.close()
        self._owned.clear()
        if not self.session.is_closed():
            self.session.close()

    def __enter__(self) -> Bus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
