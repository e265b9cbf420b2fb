"""Decoding of bus payloads: validate, count rejections by reason, never raise into a loop.

- ``decode(key, payload) -> Decoded`` is stateless and raises ``MessageError`` (an InputError
  with a ``reason``) for a bad message: for tools and tests.
- ``Decoder().decode(key, payload) -> Decoded | None`` is what loops use: it never raises; a bad
  message returns None, increments ``counts[reason]`` and is logged (rate-limited: the 1st, 2nd,
  4th, 8th ... of each reason). It also rejects, per key (one key = one publisher), a message
  whose ``seq`` is not above the last accepted one as ``'out_of_order'`` (duplicates and stale
  reorderings), except a publisher restart: ``seq`` lower but ``stamp_s`` newer than the last
  accepted stamp by ``restart_after_s`` or more (counted in ``restarts``). Skipped seq numbers
  of accepted messages add up in ``missed`` (lost in transport or dropped by a full channel).

Reasons (``REASONS``, the contract's list; a test holds the two equal): too_large, bad_key,
malformed_json, malformed_compact (:mod:`sara_app.bus.compact`), non_finite, schema_version,
missing_field, unknown_field, unknown_source, unknown_joint, missing_joint, unknown_frame,
inconsistent_length, invalid, key_mismatch, out_of_order, internal; and, counted by the worker
through ``Decoder.count``: superseded, out_of_range, stamp_not_advancing, tracking_inconsistent,
repeated, unknown_tracker, too_many_people, wrong_dof; and by a request queue
(:mod:`sara_app.bus.request_queue`): queue_full.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple

from pydantic import ValidationError

from sara_app.bus.compact import CompactError, decode_compact, is_compact
from sara_app.bus.keys import ParsedKey, parse_key
from sara_app.bus.messages import MODELS_BY_KIND, Message
from sara_app.errors import InputError

MAX_PAYLOAD_BYTES = 4 * 1024 * 1024
MAX_SMALL_PAYLOAD_BYTES = 64 * 1024
SMALL_KINDS = frozenset(
    {
        "skeleton",
        "tracker_frame",
        "robot_state",
        "retire",
        "controller_status",
        "params_ack",
        "robot_replan",
    }
)
"""Kinds whose messages are small (a 38-joint skeleton with confidences, velocities and
uncertainties is about 6 kB, a frame listing the most people it may about 18 kB): above
:data:`MAX_SMALL_PAYLOAD_BYTES` they are ``too_large`` before they are parsed. Parsed in full
up to 4 MiB, skeletons of 4 MB on one key slowed a live worker to 12 cycles a second
(hostile-tracker probe, 2026-11-30)."""
MAX_TRACKED_KEYS = 4096
REASONS: tuple[str, ...] = (
    "too_large",
    "bad_key",
    "malformed_json",
    "malformed_compact",
    "non_finite",
    "schema_version",
    "missing_field",
    "unknown_field",
    "unknown_source",
    "unknown_joint",
    "missing_joint",
    "unknown_frame",
    "inconsistent_length",
    "invalid",
    "key_mismatch",
    "out_of_order",
    "internal",
    # refused by the worker after decoding (the same counters, see ``Decoder.count``)
    "superseded",
    "out_of_range",
    "stamp_not_advancing",
    "tracking_inconsistent",
    "repeated",
    "unknown_tracker",
    "too_many_people",
    "wrong_dof",
    # a request lost to a full queue (sara_app.bus.request_queue)
    "queue_full",
)
# pydantic error type -> reason; the contract's own error types (messages.base.contract_error)
# pass through when listed.
_ERROR_REASON = {
    "missing": "missing_field",
    "extra_forbidden": "unknown_field",
    "finite_number": "non_finite",
    "too_deep": "invalid",
}

log = logging.getLogger("sara_app.bus")


class MessageError(InputError):
    """A payload that is not a valid message; ``reason`` is one of ``REASONS``."""

    def __init__(self, reason: str, message: str) -> None:
        self.reason = reason
        super().__init__(f"{reason}: {message}")


class Decoded(NamedTuple):
    """A valid message, its parsed key and its reception time (``time.time()`` seconds)."""

    key: ParsedKey
    msg: Message
    recv_s: float


_PRIORITY = {r: i for i, r in enumerate(REASONS)}


def _error_reason(e: Mapping[str, Any]) -> str:
    kind, loc, value = e["type"], e["loc"], e.get("input")
    if kind in ("json_invalid", "json_type", "model_type", "model_attributes_type") and not loc:
        return "malformed_json"
    if loc == ("schema_version",):
        return "missing_field" if kind == "missing" else "schema_version"
    if isinstance(value, float) and not math.isfinite(value):
        return "non_finite"
    return kind if kind in _PRIORITY else _ERROR_REASON.get(kind, "invalid")


def _validation_error(err: ValidationError) -> MessageError:
    errors = err.errors()
    reasons = [_error_reason(e) for e in errors]
    i = min(range(len(errors)), key=lambda k: _PRIORITY[reasons[k]])
    where = ".".join(str(p) for p in errors[i]["loc"]) or "<message>"
    text = f"{where}: {errors[i]['msg']} ({len(errors)} error(s))"
    return MessageError(reasons[i], text[:500])


def decode(key_expr: str, payload: bytes) -> Decoded:
    """Validate one payload received on ``key_expr``; raise MessageError if it is bad."""
    recv_s = time.time()
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise MessageError("too_large", f"{len(payload)} bytes > {MAX_PAYLOAD_BYTES}")
    try:
        key = parse_key(key_expr)
    except InputError as e:
        raise MessageError("bad_key", str(e)) from None
    if key.kind in SMALL_KINDS and len(payload) > MAX_SMALL_PAYLOAD_BYTES:
        raise MessageError(
            "too_large", f"{key.kind}: {len(payload)} bytes > {MAX_SMALL_PAYLOAD_BYTES}"
        )
    if is_compact(payload):  # the robot channel's binary records (sara_app.bus.compact)
        try:
            return Decoded(key, decode_compact(key.kind, payload), recv_s)
        except CompactError as e:
            raise MessageError(e.reason, e.detail) from None
    try:  # pydantic's JSON parser: strict types, NaN/Infinity/overflow refused as non-finite
        msg = MODELS_BY_KIND[key.kind].model_validate_json(payload)
    except ValidationError as e:
        raise _validation_error(e) from None
    if "schema_version" not in msg.model_fields_set:
        raise MessageError("missing_field", "schema_version is required")
    cell = getattr(msg, "cell", key.cell)
    if cell != key.cell:
        raise MessageError("key_mismatch", f"message cell {cell!r} on key {key_expr!r}")
    return Decoded(key, msg, recv_s)  # type: ignore[arg-type]


class Decoder:
    """Stateful, never-raising decoder with per-reason counters and per-key seq tracking."""

    def __init__(
        self,
        restart_after_s: float = 1.0,
        logger: logging.Logger = log,
        max_future_s: float | None = None,
        check: Callable[[Message], tuple[str, str] | None] | None = None,
    ) -> None:
        self.restart_after_s = float(restart_after_s)
        self.max_future_s = max_future_s
        self.check = check
        """The subscriber's own rule (``(reason, text)`` of a refusal, or None), judged before a
        message counts for its key's order: a message the subscriber would drop anyway (a robot
        state of another number of joints) cannot hold back its key's later messages with a
        huge ``seq``."""
        """Stamps later than the reception time by more than this are refused as
        ``out_of_range`` (before they count for the order: a stamp from the far future would
        otherwise hold back every later message of its key); None: no such check."""
        self.counts: dict[str, int] = {}
        self.accepted = 0
        self.restarts = 0
        self.missed = 0  # seq numbers skipped by accepted messages (lost or dropped upstream)
        self._last: dict[str, tuple[int, float]] = {}  # key -> (seq, stamp_s) last accepted
        self._log = logger

    @property
    def rejected(self) -> int:
        return sum(self.counts.values())

    def decode(self, key_expr: str, payload: bytes) -> Decoded | None:
        """The decoded message, or None (counted, logged) when it is rejected."""
        try:
            d = decode(key_expr, payload)
            if self.max_future_s is not None and d.msg.stamp_s > d.recv_s + self.max_future_s:
                ahead = d.msg.stamp_s - d.recv_s
                raise MessageError("out_of_range", f"stamp_s {ahead:.4g} s in the future")
            refusal = None if self.check is None else self.check(d.msg)
            if refusal is not None:
                raise MessageError(*refusal)
            self._check_order(str(key_expr), d.msg.seq, d.msg.stamp_s)
        except MessageError as e:
            self._reject(e.reason, str(key_expr), str(e))
            return None
        except Exception as e:  # noqa: BLE001 - a bad message must never end the caller's loop
            self._reject("internal", str(key_expr), repr(e))
            return None
        self.accepted += 1
        return d

    def count(self, reason: str, n: int = 1) -> None:
        """Count ``n`` messages dropped for ``reason`` (one of ``REASONS``) outside ``decode``."""
        if reason not in _PRIORITY:
            raise InputError(f"drop reason {reason!r} unknown; valid: {', '.join(REASONS)}")
        self.counts[reason] = self.counts.get(reason, 0) + n

    def reset(self, key_expr: str | None = None) -> None:
        """Forget the last seq of one key (or of all keys)."""
        if key_expr is None:
            self._last.clear()
        else:
            self._last.pop(key_expr, None)

    def _check_order(self, key_expr: str, seq: int, stamp_s: float) -> None:
        last = self._last.get(key_expr)
        if last is not None and seq <= last[0]:
            if stamp_s < last[1] + self.restart_after_s:
                raise MessageError("out_of_order", f"seq {seq} <= last {last[0]} on {key_expr}")
            self.restarts += 1
        elif last is not None:
            self.missed += seq - last[0] - 1
        elif last is None and len(self._last) >= MAX_TRACKED_KEYS:
            self._last.pop(next(iter(self._last)))
        self._last[key_expr] = (seq, stamp_s)

    def _reject(self, reason: str, key_expr: str, text: str) -> None:
        n = self.counts.get(reason, 0) + 1
        self.counts[reason] = n
        if n & (n - 1) == 0:  # 1, 2, 4, 8, ...: bounded log volume under a flood
            self._log.warning("bus: rejected message #%d (%s) on %s: %s", n, reason, key_expr, text)
