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
from typing import Any, NamedTuple, cast, get_args

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


class CommandArrays(NamedTuple):
    """A robot command as the cell worker builds it: :class:`RobotCommandMsg`'s fields with its
    vectors in ``body``, the float64 body of its compact record (``q``, ``q_dot``, ``q_ddot``
    of ``n`` joints, then ``failsafe_t_s (F,)``, offsets from ``stamp_s``, and ``failsafe_q (F,
    n)``; the properties are views into it). Published as a compact record straight from the
    body (:meth:`record`), or as JSON through the validated message (:meth:`message`). Make one
    with :meth:`build` or check one with :meth:`checked`: both refuse what the message's schema
    refuses."""

    seq: int
    stamp_s: float
    mode: str
    valid_until_s: float
    n: int
    body: np.ndarray

    @property
    def n_stop(self) -> int:
        """``F``, the stop's samples."""
        return (self.body.shape[0] - 3 * self.n) // (self.n + 1)

    @property
    def q(self) -> np.ndarray:
        return self.body[: self.n]

    @property
    def q_dot(self) -> np.ndarray:
        return self.body[self.n : 2 * self.n]

    @property
    def q_ddot(self) -> np.ndarray:
        return self.body[2 * self.n : 3 * self.n]

    @property
    def failsafe_t_s(self) -> np.ndarray:
        return self.body[3 * self.n : 3 * self.n + self.n_stop]

    @property
    def failsafe_q(self) -> np.ndarray:
        return self.body[3 * self.n + self.n_stop :].reshape(-1, self.n)

    @classmethod
    def build(
        cls, seq: int, stamp_s: float, mode: str, valid_until_s: float, q: Any, q_dot: Any,
        q_ddot: Any, failsafe_t_s: Any, failsafe_q: Any,
    ) -> CommandArrays:  # fmt: skip
        """A checked command of these fields (raises :class:`CompactError`)."""
        v = [np.asarray(a, _F8) for a in (q, q_dot, q_ddot, failsafe_t_s, failsafe_q)]
        n, F = v[0].size, v[3].size
        if F == 0 and v[4].size == 0:  # no stop: [] as well as an empty (0, n)
            v[4] = v[4].reshape(0, n)
        shapes = tuple(a.shape for a in v)
        if shapes != ((n,), (n,), (n,), (F,), (F, n)):
            raise CompactError(
                "inconsistent_length",
                f"q, q_dot, q_ddot, failsafe_t_s, failsafe_q have shapes {shapes}; expected "
                "(n,), (n,), (n,), (F,) and (F, n)",
            )
        body = np.concatenate([a.ravel() for a in v])
        return cls(seq, stamp_s, mode, valid_until_s, n, body).checked()

    def checked(self) -> CommandArrays:
        """This command, after the schema's rules (raises :class:`CompactError` with the
        contract's reason: ``inconsistent_length``, ``non_finite``, ``invalid``)."""
        n, size = self.n, self.body.shape[0]
        if self.body.ndim != 1 or n < 1 or (size - 3 * n) % (n + 1) or size < 3 * n:
            raise CompactError(
                "inconsistent_length",
                f"a body of {self.body.shape} for n = {n} joints; expected 3 n + F (n + 1)",
            )
        _check_finite(self.body)
        _check_times(self.failsafe_t_s)
        self.check_fields()
        return self

    def check_fields(self) -> None:
        """The schema's rules on the fields besides the body (:class:`CompactError`)."""
        if self.mode not in _MODE_CODES:
            raise CompactError("invalid", f"mode {self.mode!r}; valid: {', '.join(MODES)}")
        _check_header(True, self.n, self.n_stop, 0, 0, self.seq, self.stamp_s,
                      self.valid_until_s)  # fmt: skip

    def record(self) -> bytes:
        """The compact record (of a checked command)."""
        head = HEADER.pack(MAGIC, ENCODING_VERSION, *_IDS["robot_command"], self.n, self.n_stop,
                           _MODE_CODES[self.mode], 0, self.seq, self.stamp_s,
                           self.valid_until_s)  # fmt: skip
        return head + self.body.astype(_F8, copy=False).tobytes()

    def message(self) -> RobotCommandMsg:
        """The validated message (pydantic's checks: the JSON path)."""
        return RobotCommandMsg(
            seq=self.seq, stamp_s=self.stamp_s, q=self.q.tolist(), q_dot=self.q_dot.tolist(),
            q_ddot=self.q_ddot.tolist(), mode=cast(Any, self.mode),
            valid_until_s=self.valid_until_s, failsafe_t_s=self.failsafe_t_s.tolist(),
            failsafe_q=self.failsafe_q.tolist(),
        )  # fmt: skip

    def stop_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """As :meth:`RobotCommandMsg.stop_arrays`: absolute sample times ``(F,)`` and positions
        ``(F, n)``; without a stop, the set point at the stamp."""
        if self.n_stop == 0:
            return np.array([self.stamp_s]), self.q[None].copy()
        return self.failsafe_t_s + self.stamp_s, self.failsafe_q

    @classmethod
    def of(cls, msg: RobotCommandMsg) -> CommandArrays:
        """The arrays of a validated message."""
        return cls.build(msg.seq, msg.stamp_s, msg.mode, msg.valid_until_s, msg.q, msg.q_dot,
                         msg.q_ddot, msg.failsafe_t_s, msg.failsafe_q)  # fmt: skip


def encode_compact(msg: RobotStateMsg | RobotCommandMsg | CommandArrays) -> bytes:
    """The record of a validated robot state or command, or of a checked
    :class:`CommandArrays` (raises :class:`InputError` for any other message)."""
    if isinstance(msg, CommandArrays):
        return msg.record()
    if isinstance(msg, RobotCommandMsg):
        return CommandArrays.of(msg).record()
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
    if code != KIND_CODES[kind]:  # before its sizes: a command's length is not a state's
        raise CompactError("key_mismatch", f"a {KINDS_BY_CODE[code]} record on a {kind} key")
    if payload[12:16] != b"\x00\x00\x00\x00":
        raise CompactError("invalid", f"reserved bytes 12-15 are {payload[12:16].hex()}, not 0")
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
    _check_finite(body)
    _check_header(command, n, F, mode, flags, seq, stamp_s, valid_s)
    if not command:
        return RobotStateMsg.model_construct(
            schema_version=1, seq=seq, stamp_s=stamp_s, q=body[:n].tolist(),
            q_dot=body[n : 2 * n].tolist(), q_ddot=body[2 * n :].tolist() if rows == 3 else None,
        )  # fmt: skip
    t = body[3 * n : 3 * n + F]
    _check_times(t)
    fields: dict[str, Any] = {
        "schema_version": 2, "seq": seq, "stamp_s": stamp_s, "q": body[:n].tolist(),
        "q_dot": body[n : 2 * n].tolist(), "q_ddot": body[2 * n : 3 * n].tolist(),
        "mode": MODES[mode], "valid_until_s": valid_s, "failsafe_t_s": t.tolist(),
        "failsafe_q": body[3 * n + F :].reshape(F, n).tolist(),
    }  # fmt: skip
    return RobotCommandMsg.model_construct(**fields)


def _check_finite(body: np.ndarray) -> None:
    if not np.isfinite(body).all():
        raise CompactError("non_finite", "a joint value or failsafe sample is NaN or infinite")


def _check_times(t: np.ndarray) -> None:
    if t.shape[0] > 1 and not (np.diff(t) > 0.0).all():
        raise CompactError("invalid", "failsafe_t_s must increase strictly")


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
