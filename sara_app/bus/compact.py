"""The compact robot channel: robot states and commands as fixed little-endian binary records
(encoding version 1), for the two keys a cell carries at its control rate.

A JSON robot command of a 7-joint arm is about 600 bytes, and decoding it through its pydantic
model costs 9 us in a warm loop and several times that in a live cell (cold caches): the
controller decodes one per cycle and the worker decodes 1-2 states. This record carries the
same fields as the JSON message of the same schema version and is checked against the same
rules with a few numpy reductions, without building a validated model first. JSON stays
accepted on these keys (a decoder tells the two apart by the first byte: a JSON text never
starts with NUL), so an integrator may send either; :class:`~sara_app.bus.session.Bus` with
``robot_encoding="compact"`` publishes this one.

Layout (offsets in bytes; ``<`` little-endian; ``CONTRACT.md`` has the same table)::

    0   4s  magic b"\\x00SRB"
    4   u1  encoding version (1)
    5   u1  kind: 1 robot_state, 2 robot_command
    6   u1  the message kind's schema_version (state 1, command 2)
    7   u1  n: joints, 1..64
    8   u2  F: failsafe samples, 0..512 (a state: 0)
    10  u1  mode (a command: 0 intended, 1 failsafe, 2 rest, 3 fault; a state: 0)
    11  u1  flags: bit 0, the state carries q_ddot (a command always does); other bits 0
    12  4x  reserved, zero
    16  i8  seq (>= 0)
    24  f8  stamp_s
    32  f8  valid_until_s (a state: 0)
    40  f8  q (n), q_dot (n), q_ddot (n, if present), failsafe_t_s (F), failsafe_q (F x n)

Refusal reasons are the contract's: ``malformed_compact`` (too short, wrong magic, another
kind than the robot's two), ``schema_version``, ``non_finite``, ``inconsistent_length`` (the
size does not match n and F), ``invalid`` (ranges, order, reserved bits), ``key_mismatch``
(a state on the command key or the reverse).
"""

from __future__ import annotations

import struct
from typing import Any, get_args

import numpy as np

from sara_app.bus.messages import (
    MAX_FAILSAFE_SAMPLES,
    MAX_JOINTS,
    SCHEMA_VERSIONS,
    Mode,
    RobotCommandMsg,
    RobotStateMsg,
)
from sara_app.errors import InputError

MAGIC = b"\x00SRB"
ENCODING_VERSION = 1
HEADER = struct.Struct("<4sBBBBHBB4xqdd")
KIND_CODES = {"robot_state": 1, "robot_command": 2}
KINDS_BY_CODE = {v: k for k, v in KIND_CODES.items()}
MODES: tuple[str, ...] = get_args(Mode)
"""The command's modes by their code (the order of the contract's table)."""
_MODE_CODES = {m: i for i, m in enumerate(MODES)}
_SCHEMA = {kind: SCHEMA_VERSIONS[kind] for kind in KIND_CODES}
_IDS = {kind: (KIND_CODES[kind], _SCHEMA[kind]) for kind in KIND_CODES}
"""A record's kind code and schema version, per kind."""
_F8 = np.dtype("<f8")


class CompactError(InputError):
    """A payload that is not a valid compact record; ``reason`` is a contract reason."""

    def __init__(self, reason: str, message: str) -> None:
        self.reason, self.detail = reason, message
        super().__init__(f"{reason}: {message}")


def is_compact(payload: bytes) -> bool:
    """Whether ``payload`` claims this encoding (its first byte is NUL)."""
    return payload[:1] == b"\x00"


def encode_compact(msg: RobotStateMsg | RobotCommandMsg) -> bytes:
    """The record of a validated robot state or command (raises :class:`InputError` for any
    other message)."""
    if isinstance(msg, RobotCommandMsg):
        n, F = len(msg.q), len(msg.failsafe_t_s)
        head = HEADER.pack(MAGIC, ENCODING_VERSION, *_IDS["robot_command"], n, F,
                           _MODE_CODES[msg.mode], 0, msg.seq, msg.stamp_s,
                           msg.valid_until_s)  # fmt: skip
        body = np.empty(3 * n + F + F * n, dtype=_F8)
        body[:n], body[n : 2 * n], body[2 * n : 3 * n] = msg.q, msg.q_dot, msg.q_ddot
        if F:
            body[3 * n : 3 * n + F] = msg.failsafe_t_s
            body[3 * n + F :] = np.asarray(msg.failsafe_q, dtype=_F8).ravel()
        return head + body.tobytes()
    if isinstance(msg, RobotStateMsg):
        n, acc = len(msg.q), msg.q_ddot is not None
        head = HEADER.pack(MAGIC, ENCODING_VERSION, *_IDS["robot_state"], n, 0, 0, int(acc),
                           msg.seq, msg.stamp_s, 0.0)  # fmt: skip
        body = np.empty((3 if acc else 2) * n, dtype=_F8)
        body[:n], body[n : 2 * n] = msg.q, msg.q_dot
        if msg.q_ddot is not None:
            body[2 * n :] = msg.q_ddot
        return head + body.tobytes()
    raise InputError(
        f"the compact encoding carries robot states and commands, not {type(msg).__name__}"
    )


def decode_compact(kind: str, payload: bytes) -> RobotStateMsg | RobotCommandMsg:
    """The message of a record received on a key of ``kind`` (a kind of
    :mod:`sara_app.bus.keys`); raises :class:`CompactError` with the contract's reason."""
    if len(payload) < HEADER.size or payload[:4] != MAGIC:
        raise CompactError("malformed_compact", f"{len(payload)} bytes without the header")
    magic, version, code, schema, n, F, mode, flags, seq, stamp_s, valid_s = HEADER.unpack_from(
        payload
    )
    if code not in KINDS_BY_CODE or kind not in KIND_CODES:
        raise CompactError(
            "malformed_compact",
            f"kind code {code} on a {kind} key; the compact encoding carries "
            f"{', '.join(f'{c} ({k})' for k, c in KIND_CODES.items())} only",
        )
    if version != ENCODING_VERSION or schema != _SCHEMA[KINDS_BY_CODE[code]]:
        raise CompactError(
            "schema_version",
            f"encoding version {version}, schema_version {schema}; this cell implements "
            f"encoding {ENCODING_VERSION} with schema_version {_SCHEMA[KINDS_BY_CODE[code]]}",
        )
    if not (np.isfinite(stamp_s) and np.isfinite(valid_s)):
        raise CompactError("non_finite", f"stamp_s {stamp_s}, valid_until_s {valid_s}")
    command = code == 2
    rows = 3 if command or flags & 1 else 2
    count = rows * n + F + F * n
    if len(payload) != HEADER.size + 8 * count:
        raise CompactError(
            "inconsistent_length",
            f"{len(payload)} bytes; n = {n} joints and F = {F} failsafe samples need "
            f"{HEADER.size + 8 * count}",
        )
    body = np.frombuffer(payload, dtype=_F8, offset=HEADER.size)
    if not np.isfinite(body).all():
        raise CompactError("non_finite", "a joint value or failsafe sample is NaN or infinite")
    _check_header(command, n, F, mode, flags, seq, stamp_s, valid_s)
    if code != KIND_CODES[kind]:
        raise CompactError("key_mismatch", f"a {KINDS_BY_CODE[code]} record on a {kind} key")
    if not command:
        return RobotStateMsg.model_construct(
            schema_version=1, seq=seq, stamp_s=stamp_s, q=body[:n].tolist(),
            q_dot=body[n : 2 * n].tolist(), q_ddot=body[2 * n :].tolist() if rows == 3 else None,
        )  # fmt: skip
    t = body[3 * n : 3 * n + F]
    if F > 1 and not (np.diff(t) > 0.0).all():
        raise CompactError("invalid", "failsafe_t_s must increase strictly")
    fields: dict[str, Any] = {
        "schema_version": 2, "seq": seq, "stamp_s": stamp_s, "q": body[:n].tolist(),
        "q_dot": body[n : 2 * n].tolist(), "q_ddot": body[2 * n : 3 * n].tolist(),
        "mode": MODES[mode], "valid_until_s": valid_s, "failsafe_t_s": t.tolist(),
        "failsafe_q": body[3 * n + F :].reshape(F, n).tolist(),
    }  # fmt: skip
    return RobotCommandMsg.model_construct(**fields)


def _check_header(
    command: bool, n: int, F: int, mode: int, flags: int, seq: int, stamp_s: float, valid_s: float
) -> None:
    """The ranges the JSON schema sets, on the header's fields (:class:`CompactError`)."""
    problems = []
    if not 1 <= n <= MAX_JOINTS:
        problems.append(f"n = {n} joints, expected 1..{MAX_JOINTS}")
    if seq < 0 or stamp_s < 0.0:
        problems.append(f"seq {seq} and stamp_s {stamp_s} must be >= 0")
    if command:
        if F > MAX_FAILSAFE_SAMPLES or mode >= len(MODES) or flags:
            problems.append(
                f"F = {F} (at most {MAX_FAILSAFE_SAMPLES}), mode code {mode} (0-3: "
                f"{', '.join(MODES)}), flags {flags} (0)"
            )
        if valid_s < stamp_s:
            problems.append(f"valid_until_s {valid_s} is before stamp_s {stamp_s}")
    elif F or mode or flags > 1 or valid_s != 0.0:
        problems.append(
            f"a state has F = {F}, mode {mode}, flags {flags}, valid_until_s {valid_s}; "
            "expected 0, 0, 0 or 1, 0"
        )
    if problems:
        raise CompactError("invalid", "; ".join(problems))
