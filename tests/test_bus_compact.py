"""The compact robot channel (sara_app.bus.compact): round trips, the same refusals as the JSON
schema (the pydantic models are the oracle), byte-level fuzzing, the contract's snippet, and a
real zenoh session publishing compact on the robot keys only."""

from __future__ import annotations

import re
import struct
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from pydantic import ValidationError

from sara_app.bus import keys
from sara_app.bus.codec import Decoder, MessageError, decode
from sara_app.bus.compact import HEADER, MAGIC, encode_compact
from sara_app.bus.messages import RobotCommandMsg, RobotStateMsg, StatusMsg, encode
from sara_app.bus.session import Bus, free_port
from sara_app.errors import InputError, ParameterError

STATE_KEY, COMMAND_KEY = keys.robot_state_key("c1"), keys.robot_command_key("c1")
CONTRACT = Path(__file__).resolve().parents[1] / "sara_app" / "bus" / "CONTRACT.md"


def _command(rng: np.random.Generator, n: int = 7, F: int = 4, **change: Any) -> RobotCommandMsg:
    t0 = float(rng.uniform(0, 2e9))
    fields: dict[str, Any] = {
        "seq": int(rng.integers(0, 2**62)), "stamp_s": t0, "q": rng.normal(size=n).tolist(),
        "q_dot": rng.normal(size=n).tolist(), "q_ddot": rng.normal(size=n).tolist(),
        "mode": str(rng.choice(["intended", "failsafe", "rest", "fault"])),
        "valid_until_s": t0 + 0.004, "failsafe_t_s": np.cumsum(rng.uniform(1e-4, 0.1, F)).tolist(),
        "failsafe_q": rng.normal(size=(F, n)).tolist(),
    }  # fmt: skip
    return RobotCommandMsg(**(fields | change))


def _state(rng: np.random.Generator, n: int = 7, acc: bool = False) -> RobotStateMsg:
    return RobotStateMsg(
        seq=int(rng.integers(0, 2**62)), stamp_s=float(rng.uniform(0, 2e9)),
        q=rng.normal(size=n).tolist(), q_dot=rng.normal(size=n).tolist(),
        q_ddot=rng.normal(size=n).tolist() if acc else None,
    )  # fmt: skip


def test_round_trips_equal_the_json_path() -> None:
    rng = np.random.default_rng(3)
    for i in range(200):
        n, F = int(rng.integers(1, 65)), int(rng.integers(0, 20))
        for key, msg in (
            (COMMAND_KEY, _command(rng, n, F)),
            (STATE_KEY, _state(rng, n, acc=bool(i % 2))),
        ):
            record = encode_compact(msg)
            got = decode(key, record).msg
            assert type(got) is type(msg)
            assert got.model_dump() == msg.model_dump() == decode(key, encode(msg)).msg.model_dump()
            assert encode(got) == encode(msg)  # re-encodes to the same JSON
    assert len(encode_compact(_command(rng))) < len(encode(_command(rng))) * 0.8


def test_only_robot_messages_have_a_record() -> None:
    with pytest.raises(InputError, match="StatusMsg"):
        encode_compact(StatusMsg(seq=0, stamp_s=1.0, cell="c", state="running"))  # type: ignore[arg-type]


def _record(kind: int, n: int, F: int, mode: int, flags: int, seq: int, stamp: float,
            valid: float, values: list[float], version: int = 1, schema: int | None = None,
            magic: bytes = MAGIC) -> bytes:  # fmt: skip
    schema = kind if schema is None else schema
    head = HEADER.pack(magic, version, kind, schema, n, F, mode, flags, seq, stamp, valid)
    return head + np.asarray(values, dtype="<f8").tobytes()


N = 2
GOOD_CMD = dict(kind=2, n=N, F=2, mode=0, flags=0, seq=1, stamp=10.0, valid=10.01,
                values=[0.1, 0.2, 0, 0, 0, 0, 0.002, 0.05, 0.1, 0.2, 0.1, 0.2])  # fmt: skip
GOOD_STATE = dict(kind=1, n=N, F=0, mode=0, flags=0, seq=1, stamp=10.0, valid=0.0,
                  values=[0.1, 0.2, 0.0, 0.0])  # fmt: skip


def _json_of(c: dict[str, Any]) -> dict[str, Any] | None:
    """The JSON message of the same content, where one exists (None: no JSON equivalent)."""
    n, F, v = c["n"], c["F"], list(c["values"])
    base = {"schema_version": c["kind"], "seq": c["seq"], "stamp_s": c["stamp"]}
    if c["kind"] == 1:
        rows = 3 if c["flags"] & 1 else 2
        if len(v) != rows * n or c["F"] or c["mode"] or c["valid"] or c["flags"] > 1:
            return None
        acc = {"q_ddot": v[2 * n :]} if rows == 3 else {}
        return base | {"q": v[:n], "q_dot": v[n : 2 * n]} | acc
    if len(v) != 3 * n + F + F * n or c["flags"] or c["mode"] > 3:
        return None
    modes = ("intended", "failsafe", "rest", "fault")
    return base | {
        "q": v[:n], "q_dot": v[n : 2 * n], "q_ddot": v[2 * n : 3 * n], "mode": modes[c["mode"]],
        "valid_until_s": c["valid"], "failsafe_t_s": v[3 * n : 3 * n + F],
        "failsafe_q": [v[3 * n + F + i * n : 3 * n + F + (i + 1) * n] for i in range(F)],
    }  # fmt: skip


NAN, INF = float("nan"), float("inf")
V = GOOD_CMD["values"]
SWAPPED_T, EQUAL_T = V[:6] + [0.05, 0.002] + V[8:], V[:6] + [0.05, 0.05] + V[8:]
MANY_F = [0.0] * 3 + list(np.arange(1, 514) * 1e-3) + [0.0] * 513
BAD: list[tuple[str, dict[str, Any], dict[str, Any]]] = [
    ("non_finite", GOOD_CMD, {"stamp": NAN}),
    ("non_finite", GOOD_CMD, {"valid": INF}),
    ("non_finite", GOOD_CMD, {"values": [NAN] + GOOD_CMD["values"][1:]}),
    ("non_finite", GOOD_CMD, {"values": GOOD_CMD["values"][:-1] + [-INF]}),
    ("non_finite", GOOD_STATE, {"values": [0.1, INF, 0.0, 0.0]}),
    ("invalid", GOOD_CMD, {"seq": -1}),
    ("invalid", GOOD_CMD, {"stamp": -1.0, "valid": 0.0}),
    ("invalid", GOOD_CMD, {"valid": 9.0}),
    ("invalid", GOOD_CMD, {"values": SWAPPED_T}),
    ("invalid", GOOD_CMD, {"values": EQUAL_T}),
    ("invalid", GOOD_CMD, {"mode": 4}),
    ("invalid", GOOD_CMD, {"flags": 1}),
    ("invalid", GOOD_STATE, {"seq": -5}),
    ("invalid", GOOD_STATE, {"mode": 1}),
    ("invalid", GOOD_STATE, {"flags": 2}),
    ("invalid", GOOD_STATE, {"valid": 3.0}),
    ("invalid", GOOD_STATE, {"n": 0, "values": []}),
    ("invalid", GOOD_CMD, {"n": 65, "F": 0, "values": [0.0] * 195}),
    ("invalid", GOOD_CMD, {"F": 513, "n": 1, "values": MANY_F}),
    ("inconsistent_length", GOOD_CMD, {"values": GOOD_CMD["values"][:-1]}),
    ("inconsistent_length", GOOD_STATE, {"flags": 1}),
    ("inconsistent_length", GOOD_STATE, {"values": [0.1, 0.2, 0.0, 0.0, 0.0]}),
    ("schema_version", GOOD_CMD, {"version": 2}),
    ("schema_version", GOOD_CMD, {"schema": 1}),
    ("schema_version", GOOD_STATE, {"schema": 2}),
    ("malformed_compact", GOOD_STATE, {"kind": 3}),
    ("malformed_compact", GOOD_STATE, {"magic": b"\x00SRC"}),
]  # fmt: skip


@pytest.mark.parametrize(("reason", "good", "change"), BAD)
def test_refusals_match_the_json_schema(
    reason: str, good: dict[str, Any], change: dict[str, Any]
) -> None:
    c = good | change
    key = STATE_KEY if good is GOOD_STATE else COMMAND_KEY
    with pytest.raises(MessageError) as e:
        decode(key, _record(**c))
    assert e.value.reason == reason
    as_json = _json_of(c)
    if as_json is not None and reason in ("invalid", "inconsistent_length"):
        model = RobotStateMsg if good is GOOD_STATE else RobotCommandMsg
        with pytest.raises(ValidationError):  # the oracle refuses the same content
            model.model_validate(as_json)
    for good_c, k in ((GOOD_CMD, COMMAND_KEY), (GOOD_STATE, STATE_KEY)):
        assert decode(k, _record(**good_c)).msg.seq == 1  # type: ignore[arg-type]


def test_a_record_on_the_wrong_key_or_a_short_one() -> None:
    state = _record(**GOOD_STATE)  # type: ignore[arg-type]
    for key, payload, reason in (
        (COMMAND_KEY, state, "key_mismatch"),
        (STATE_KEY, _record(**GOOD_CMD), "key_mismatch"),  # type: ignore[arg-type]
        (keys.verdict_key("c1"), state, "malformed_compact"),
        (keys.skeleton_key("c1", "p1"), state, "malformed_compact"),
        (STATE_KEY, b"\x00", "malformed_compact"),
        (STATE_KEY, state[:39], "malformed_compact"),
        # a state's size with the command's kind code: the key says what it is not
        (STATE_KEY, _record(**(GOOD_STATE | {"kind": 2, "schema": 2})), "key_mismatch"),
        (STATE_KEY, state[:12] + b"\x00\x00\x07\x00" + state[16:], "invalid"),  # reserved
    ):
        with pytest.raises(MessageError) as e:
            decode(key, payload)
        assert e.value.reason == reason, (key, len(payload))


def test_fuzzed_records_never_raise_and_never_pass_what_json_refuses() -> None:
    """Truncations, byte flips and random tails of valid records: the decoder refuses with a
    contract reason, or accepts a message that the pydantic model validates as well."""
    rng = np.random.default_rng(11)
    dec = Decoder()
    accepted = 0
    for i in range(3000):
        msg: Any = (
            _command(rng, 7, int(rng.integers(0, 6))) if i % 2 else _state(rng, 7, i % 4 == 0)
        )
        key = COMMAND_KEY if i % 2 else STATE_KEY
        b = bytearray(encode_compact(msg))
        how = i % 3
        if how == 0:
            b = b[: int(rng.integers(0, len(b)))]
        elif how == 1:
            for _ in range(int(rng.integers(1, 4))):
                b[int(rng.integers(0, len(b)))] = int(rng.integers(0, 256))
        else:
            b += rng.bytes(8 * int(rng.integers(1, 3)))
        d = dec.decode(key, bytes(b))
        if d is not None:
            accepted += 1
            type(d.msg).model_validate(d.msg.model_dump())  # raises if JSON would refuse it
    assert dec.accepted == accepted and dec.rejected == 3000 - accepted
    assert accepted > 100 and dec.counts.get("internal", 0) == 0
    assert {"malformed_compact", "inconsistent_length"} <= set(dec.counts)


def test_the_contract_snippet_makes_a_state() -> None:
    text = CONTRACT.read_text()
    (snippet,) = re.findall(r"```py\n(.*?)```", text, flags=re.S)
    scope: dict[str, Any] = {"seq": 7, "stamp_s": 123.5}
    exec(snippet, scope)  # noqa: S102 - the documentation's own example
    msg = decode(STATE_KEY, scope["record"]).msg
    assert isinstance(msg, RobotStateMsg) and msg.seq == 7 and msg.q == [0.0] * 7
    assert struct.unpack_from("<4s", scope["record"])[0] == MAGIC


def test_a_compact_session_publishes_records_on_the_robot_keys_only() -> None:
    port = free_port()
    with pytest.raises(ParameterError, match="valid: json, compact"):
        Bus(None, robot_encoding="msgpack")  # type: ignore[arg-type]
    with Bus.router(port) as hub, Bus.client(port, robot_encoding="compact") as bus:
        raw: list[tuple[str, bytes]] = []
        sub = hub.session.declare_subscriber(
            "sara/c1/**", lambda s: raw.append((str(s.key_expr), s.payload.to_bytes()))
        )
        decoded = hub.subscribe("sara/c1/**", fifo=True)
        pubs = {k: bus.publisher(k) for k in (STATE_KEY, COMMAND_KEY, keys.status_key("c1"))}
        deadline = time.monotonic() + 5
        while not all(p.has_subscribers() for p in pubs.values()) and time.monotonic() < deadline:
            time.sleep(0.01)
        rng = np.random.default_rng(5)
        sent = {STATE_KEY: _state(rng), COMMAND_KEY: _command(rng),
                keys.status_key("c1"): StatusMsg(seq=0, stamp_s=1.0, cell="c1",
                                                 state="running")}  # fmt: skip
        # one at a time: a burst of puts can outrun zenoh's transmit queue (DROP congestion
        # control) while this process's transmit thread waits for a CPU
        deadline = time.monotonic() + 5
        for n, (k, m) in enumerate(sent.items(), start=1):
            assert pubs[k].put(m)
            while len(raw) < n and time.monotonic() < deadline:
                time.sleep(0.01)
        sub.undeclare()
        first = {k: p[:1] for k, p in raw}
        assert first == {STATE_KEY: b"\x00", COMMAND_KEY: b"\x00", keys.status_key("c1"): b"{"}
        got = {d.key.kind: d.msg for d in decoded.drain().messages}
        assert got["robot_state"].model_dump() == sent[STATE_KEY].model_dump()
        assert got["robot_command"].model_dump() == sent[COMMAND_KEY].model_dump()
