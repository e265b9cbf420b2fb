"""The cell's Zenoh bus: key expressions, JSON message schemas, decoding, sessions.

- ``keys``: every key expression (``sara/<cell>/...``), builders, ``parse_key``.
- ``messages``: pydantic models of the payloads (schema version 1) and ``encode``.
- ``codec``: ``decode`` (raises ``MessageError``) and ``Decoder`` (never raises; counts
  rejections by reason; rejects out-of-order ``seq`` per key).
- ``session``: loopback zenoh configs, ``Bus`` with non-blocking ``Subscription.drain()`` and
  ``Publisher.put()``.
- ``CONTRACT.md``: the contract for other programs; ``example_publisher.py``: a plain-zenoh
  client that publishes skeletons.

The verification core imports nothing from here; this package imports the core's skeleton
tables only. ``sara_app.bus.session`` imports zenoh; the other modules do not.
"""

from sara_app.bus.codec import REASONS, Decoded, Decoder, MessageError, decode
from sara_app.bus.messages import (
    SCHEMA_VERSION,
    OccupancyMsg,
    ParamsAckMsg,
    ParamsMsg,
    RobotCommandMsg,
    RobotStateMsg,
    SkeletonMsg,
    StatusMsg,
    VerdictMsg,
    encode,
)

__all__ = [
    "REASONS",
    "SCHEMA_VERSION",
    "Decoded",
    "Decoder",
    "MessageError",
    "OccupancyMsg",
    "ParamsAckMsg",
    "ParamsMsg",
    "RobotCommandMsg",
    "RobotStateMsg",
    "SkeletonMsg",
    "StatusMsg",
    "VerdictMsg",
    "decode",
    "encode",
]
