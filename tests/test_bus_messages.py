"""Message schemas and decoding: round trips, every rejection reason, seq order, fuzzing."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sara_app.bus.codec import (
    MAX_PAYLOAD_BYTES,
    MAX_SMALL_PAYLOAD_BYTES,
    REASONS,
    SMALL_KINDS,
    Decoder,
    MessageError,
    decode,
)
from sara_app.bus.examples import example_messages
from sara_app.bus.keys import KINDS
from sara_app.bus.messages import SCHEMA_VERSIONS, CapsulesMsg, SkeletonMsg, encode, source_points
from sara_app.errors import SaraError
from sara_app.human.skeleton import COCO17_NAMES, SOURCES, from_source, skeleton
from sara_app.human.trackers import UNIT_M

EXAMPLES = example_messages()
SKEL_KEY = EXAMPLES["skeleton"][0]


def _skel(**change: Any) -> dict[str, Any]:
    data = json.loads(encode(EXAMPLES["skeleton"][1]))
    data.update(change)
    return data


def _reason(key: str, data: Any) -> str:
    payload = data if isinstance(data, bytes) else json.dumps(data).encode()
    with pytest.raises(MessageError) as e:
        decode(key, payload)
    assert e.value.reason in REASONS
    return e.value.reason


def test_there_is_an_example_of_every_kind() -> None:
    assert sorted(EXAMPLES) == sorted(KINDS)


CURRENT_VERSIONS = {
    "verdict": 4, "robot_command": 2, "occupancy": 3,
    "params": 2, "status": 3, "controller_status": 2,  # fields added, 2026-11-30
}  # fmt: skip
# status 3 since 2026-12-02: the phase lock's state
"""The contract's version of each kind not at 1 (CONTRACT.md, "Every message has")."""


@pytest.mark.parametrize("kind", sorted(EXAMPLES))
def test_every_example_round_trips(kind: str) -> None:
    key, msg = EXAMPLES[kind]
    d = decode(key, encode(msg))
    assert d.msg == msg and d.key.kind == kind and d.key.cell == "cell1"
    data = json.loads(encode(msg))
    assert data["schema_version"] == SCHEMA_VERSIONS[kind] and data["seq"] == 42
    assert SCHEMA_VERSIONS[kind] == CURRENT_VERSIONS.get(kind, 1)
    # an older version of the kind is refused loudly, never misread (the versioning rule)
    for old in range(1, SCHEMA_VERSIONS[kind]):
        assert _reason(key, {**data, "schema_version": old}) == "schema_version"
    # every field is required or defaulted as documented: dropping an optional one still decodes
    pairs = {"failsafe_t_s": "failsafe_q", "failsafe_q": "failsafe_t_s"}  # go together
    for field, info in type(msg).model_fields.items():
        if not info.is_required() and field != "schema_version":
            gone = {field, pairs.get(field, field)}
            decode(key, json.dumps({k: v for k, v in data.items() if k not in gone}).encode())


def test_joint_mapping_matches_the_reach_code() -> None:
    rng = np.random.default_rng(0)
    for source in SOURCES:
        required, allowed = source_points(source)
        joints = {n: rng.normal(size=3).tolist() for n in sorted(allowed)}
        vel = {n: rng.normal(size=3).tolist() for n in sorted(required)}
        msg = SkeletonMsg(seq=0, stamp_s=1.0, source=source, joints=joints, velocities=vel)
        y_m, v_mps = msg.to_arrays()
        sk = skeleton(msg.kind)
        assert y_m.shape == v_mps.shape == (sk.n_joints, 3)  # type: ignore[union-attr]
        np.testing.assert_allclose(y_m, from_source(source, joints), rtol=1e-15, atol=1e-15)
        np.testing.assert_allclose(v_mps, from_source(source, vel), rtol=1e-15, atol=1e-15)  # type: ignore[arg-type]
        table = SOURCES[source][1]
        unit = UNIT_M.get(source, 1.0)  # millimetres for Azure Kinect
        for i, j in enumerate(sk.joints):  # virtual joints are means, velocities too
            np.testing.assert_allclose(y_m[i], unit * np.mean([joints[n] for n in table[j]], 0))
            np.testing.assert_allclose(v_mps[i], unit * np.mean([vel[n] for n in table[j]], 0))  # type: ignore[index]
    assert source_points("coco17")[1] == frozenset(COCO17_NAMES)
    y = rng.normal(size=(15, 3))
    back = SkeletonMsg.from_arrays("full", y, seq=1, stamp_s=2.0, v_mps=-y).to_arrays()
    np.testing.assert_array_equal(back[0], y)
    np.testing.assert_array_equal(back[1], -y)  # type: ignore[arg-type]


def _without_joint(data: dict[str, Any], name: str) -> dict[str, Any]:
    data["joints"].pop(name)
    return data


BAD_SKELETONS: list[tuple[str, Any]] = [
    ("malformed_json", b'{"schema_version": 1, "seq": '),
    ("malformed_json", b"\xff\xfe\x00"),
    ("malformed_json", b"[1, 2, 3]"),
    ("non_finite", json.dumps(_skel(stamp_s=float("nan"))).encode()),  # NaN token
    ("non_finite", json.dumps(_skel(position_uncertainty_m=float("-inf"))).encode()),
    ("non_finite", json.dumps(_skel(stamp_s=1.0)).replace("1.0,", "1e999,", 1).encode()),
    ("schema_version", _skel(schema_version=2)),
    ("schema_version", _skel(schema_version="1")),
    ("schema_version", _skel(schema_version=True)),
    ("missing_field", {k: v for k, v in _skel().items() if k != "schema_version"}),
    ("missing_field", {k: v for k, v in _skel().items() if k != "seq"}),
    ("missing_field", {k: v for k, v in _skel().items() if k != "joints"}),
    ("unknown_field", _skel(colour="red")),
    ("unknown_source", _skel(source="kinect")),
    ("unknown_frame", _skel(frame="camera")),
    ("unknown_joint", _skel(joints=_skel()["joints"] | {"l_knee": [0, 0, 0]})),
    ("unknown_joint", _skel(velocities=_skel()["velocities"] | {"nose": [0, 0, 0]})),
    ("missing_joint", _without_joint(_skel(), "r_wrist")),
    ("invalid", _skel(seq=-1)),
    ("invalid", _skel(seq=True)),
    ("invalid", _skel(stamp_s="1.0")),
    ("invalid", _skel(joints=_skel()["joints"] | {"head": [1.0, 2.0]})),
    ("invalid", _skel(position_uncertainty_m=-0.1)),
]


@pytest.mark.parametrize(("reason", "data"), BAD_SKELETONS)
def test_bad_skeletons_are_rejected_with_their_reason(reason: str, data: Any) -> None:
    assert _reason(SKEL_KEY, data) == reason
    dec = Decoder()
    payload = data if isinstance(data, bytes) else json.dumps(data).encode()
    assert dec.decode(SKEL_KEY, payload) is None
    assert dec.counts == {reason: 1} and dec.accepted == 0


def _example(kind: str, **change: Any) -> tuple[str, dict[str, Any]]:
    key, msg = EXAMPLES[kind]
    return key, json.loads(encode(msg)) | change


LOCK = {"reference": "h1", "delay_s": 0.0012, "hits": 5, "misses": 0}
BAD_PHASE_LOCKS: list[tuple[str, Any]] = [
    ("non_finite", LOCK | {"delay_s": float("nan")}),
    ("invalid", LOCK | {"reference": "../x"}),
    ("invalid", LOCK | {"hits": -1}),
    ("invalid", LOCK | {"misses": 1.5}),
    ("unknown_field", LOCK | {"locked": True}),
    ("missing_field", {k: v for k, v in LOCK.items() if k != "delay_s"}),
    ("invalid", "locked"),
]


@pytest.mark.parametrize(("reason", "lock"), BAD_PHASE_LOCKS)
def test_a_status_with_a_bad_phase_lock_is_refused(reason: str, lock: Any) -> None:
    """The worker's status reports the phase lock (schema 3): a status whose lock is not a
    finite delay, two counts >= 0 and a valid person id is refused with its reason."""
    key, data = _example("status", phase_lock=lock)
    assert _reason(key, data) == reason
    assert decode(key, json.dumps(data | {"phase_lock": LOCK}).encode()).msg.phase_lock


def test_other_kinds_check_lengths_keys_and_nesting() -> None:
    key, d = _example("robot_state", q_dot=[0.0] * 6)
    assert _reason(key, d) == "inconsistent_length"
    key, d = _example("robot_command", mode="stop")
    assert _reason(key, d) == "invalid"
    key, d = _example("verdict", cell="cell2")
    assert _reason(key, d) == "key_mismatch"
    key, d = _example("params", scenario={"a": [{"b": 1.0}]})
    assert _reason(key, json.dumps(d).replace("1.0", "-1e999").encode()) == "non_finite"
    key, d = _example("occupancy")
    d["robot"]["n_intervals"] = 2
    assert _reason(key, d) == "inconsistent_length"
    key, d = _example("occupancy")
    d["humans"][0]["models"]["vel"]["ends_m"].append(0.0)
    assert _reason(key, d) == "inconsistent_length"
    key, d = _example("occupancy")
    d["humans"][0]["joints_m"] = d["humans"][0]["joints_m"][:-3]
    assert _reason(key, d) == "inconsistent_length"
    _, d = _example("verdict")
    assert _reason("sara/cell1/verdicts", d) == "bad_key"
    assert _reason(SKEL_KEY, b" " * (MAX_PAYLOAD_BYTES + 1)) == "too_large"


def test_small_kinds_are_too_large_above_64_kib_before_they_are_parsed() -> None:
    """A skeleton, frame or robot state above 64 KiB is refused by its size alone (parsing 4 MB
    skeletons held a live worker's loop up); the largest legitimate ones are far below."""
    import time

    _, skel = _example("skeleton")
    padded = json.dumps(skel).encode()
    padded = padded[:-1] + b" " * (MAX_SMALL_PAYLOAD_BYTES - len(padded)) + b"}"
    assert len(padded) == MAX_SMALL_PAYLOAD_BYTES
    decode(SKEL_KEY, padded)  # at the limit: parsed and taken
    big = b"{" + b'"x": 1, ' * 500_000 + b'"y": 2}'
    t0 = time.perf_counter()
    for kind in sorted(SMALL_KINDS):
        assert _reason(EXAMPLES[kind][0], big) == "too_large", kind
    assert time.perf_counter() - t0 < 1.0  # six 4 MB payloads not parsed
    key, occupancy = _example("occupancy")  # display messages may be larger
    assert len(json.dumps(occupancy)) < MAX_SMALL_PAYLOAD_BYTES
    assert SMALL_KINDS <= set(KINDS) and "occupancy" not in SMALL_KINDS
    assert "params" not in SMALL_KINDS  # a whole scenario
    ends, radius = np.arange(24.0).reshape(2, 2, 2, 3), np.array([[0.1, 0.2], [0.3, 0.4]])
    e2, r2 = CapsulesMsg.from_arrays(ends, radius).arrays()
    np.testing.assert_array_equal(e2, ends.reshape(-1, 2, 3))
    np.testing.assert_array_equal(r2, radius.ravel())


def _with_seq(seq: int, stamp_s: float) -> bytes:
    return json.dumps(_skel(seq=seq, stamp_s=stamp_s)).encode()


def test_seq_order_per_key() -> None:
    dec = Decoder(restart_after_s=1.0)
    other = "sara/cell1/human/h2/skeleton"
    assert dec.decode(SKEL_KEY, _with_seq(5, 10.0)) is not None
    assert dec.decode(SKEL_KEY, _with_seq(5, 10.0)) is None  # duplicate
    assert dec.decode(SKEL_KEY, _with_seq(4, 10.5)) is None  # stale reordering
    assert dec.decode(other, _with_seq(0, 10.0)) is not None  # another publisher
    assert dec.decode(SKEL_KEY, _with_seq(9, 10.1)) is not None
    assert dec.missed == 3
    assert dec.decode(SKEL_KEY, _with_seq(0, 11.2)) is not None  # restart: 1 s newer
    assert dec.restarts == 1
    assert dec.decode(SKEL_KEY, _with_seq(1, 11.3)) is not None
    assert dec.counts == {"out_of_order": 2} and dec.accepted == 5 and dec.rejected == 2
    dec.reset(SKEL_KEY)
    assert dec.decode(SKEL_KEY, _with_seq(0, 11.3)) is not None


def test_a_subscribers_check_refuses_before_the_order_counts() -> None:
    """A message the subscriber's own rule refuses (here: every seq above 100) is counted under
    the rule's reason and never advances its key's order (a refused state with a huge seq held
    the real controller's back)."""
    dec = Decoder(check=lambda m: ("wrong_dof", "too high") if m.seq > 100 else None)
    assert dec.decode(SKEL_KEY, _with_seq(5, 10.0)) is not None
    assert dec.decode(SKEL_KEY, _with_seq(10**12, 10.1)) is None
    assert dec.decode(SKEL_KEY, _with_seq(6, 10.2)) is not None  # not out of order
    assert dec.counts == {"wrong_dof": 1}


json_values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner),
    max_leaves=20,
)


@settings(max_examples=150, deadline=None)
@given(
    raw=st.binary(max_size=64),
    field=st.sampled_from(sorted(_skel())),
    value=json_values,
    kind=st.sampled_from(sorted(EXAMPLES)),
)
def test_decoder_never_raises(raw: bytes, field: str, value: Any, kind: str) -> None:
    dec = Decoder()
    key, data = _example(kind)
    data[field] = value
    for payload in (raw, json.dumps(data).encode(), json.dumps(data)[:-1].encode()):
        got = dec.decode(key, payload)  # must not raise
        dec.reset()
        assert got is None or type(got.msg) is type(EXAMPLES[kind][1])
    assert dec.accepted + dec.rejected == 3
    assert set(dec.counts) <= set(REASONS) - {"internal"}


def test_contract_examples_decode() -> None:
    text = (Path(__file__).resolve().parents[1] / "sara_app/bus/CONTRACT.md").read_text()
    blocks = re.findall(r"Example on `([^`]+)`:\s*```json\n(.*?)```", text, flags=re.S)
    kinds = set()
    for key, payload in blocks:
        d = decode(key, payload.encode())
        kinds.add(d.key.kind)
        assert d.msg == EXAMPLES[d.key.kind][1]  # the document shows the tested examples
    assert kinds == set(EXAMPLES)


def test_every_drop_reason_in_the_code_is_in_the_contract_and_back() -> None:
    """The contract's table of refusal reasons lists exactly the decoder's ``REASONS`` (every
    counter the worker can raise goes through ``Decoder.count``, which refuses others)."""
    text = (Path(__file__).resolve().parents[1] / "sara_app/bus/CONTRACT.md").read_text()
    table = text.split("| reason | refused because |")[1].split("\n\n")[0]
    listed = set()
    for line in table.splitlines()[2:]:
        first = line.split("|")[1]
        listed |= set(re.findall(r"`([a-z_]+)`", first))
    assert listed == set(REASONS)
    with pytest.raises(SaraError, match="unknown"):
        Decoder().count("made_up_reason")
