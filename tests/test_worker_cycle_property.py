"""Property: whatever arrives on a person's key (coordinates up to +-1e308, NaN, wrong shapes,
stamps in the past and future, id churn, garbage bytes), every cycle of the real worker publishes
exactly one verdict and then one command over zenoh, and ``intended`` only when the cycle was
verified and nothing is wrong."""

from __future__ import annotations

import json
import time
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sara_app.bus import keys
from sara_app.bus.compact import CommandArrays
from sara_app.bus.messages import RobotCommandMsg, VerdictMsg
from sara_app.bus.session import Bus, free_port
from sara_app.human.skeleton import skeleton
from sara_app.runtime.worker import CellWorker
from sara_app.scenario import load_scenario

CELL = "prop"
NAMES = skeleton("full").joints

coords = st.one_of(
    st.floats(-1e308, 1e308),
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-3.0, 3.0),
)
point = st.one_of(st.lists(coords, min_size=3, max_size=3), st.lists(coords, max_size=5))


@st.composite
def payloads(draw: Any) -> tuple[str, bytes]:
    hid = draw(
        st.sampled_from(["p1", "p2", "p3", "x" * 64, "churn" + str(draw(st.integers(0, 99)))])
    )
    kind = draw(st.sampled_from(["skeleton", "skeleton", "skeleton", "garbage"]))
    if kind == "garbage":
        return hid, draw(st.binary(max_size=200))
    names = draw(st.sampled_from([NAMES, NAMES[:9], NAMES[:-1]]))
    joints = {n: draw(point) for n in names}
    msg: dict[str, Any] = {
        "schema_version": 1,
        "seq": draw(st.integers(0, 2**63 - 1)),
        "stamp_s": time.time() + draw(st.sampled_from([0.0, -0.01, -5.0, 0.5, 1e9, -1e9])),
        "source": draw(st.sampled_from(["sara_full", "sara_full", "sara_upper", "coco17"])),
        "joints": joints,
    }
    if draw(st.booleans()):
        msg["position_uncertainty_m"] = draw(st.floats(0, 1))
    text = json.dumps(msg, allow_nan=True)  # NaN / Infinity literals as a hostile sender would
    return hid, text.encode()


@pytest.fixture(scope="module")
def live():
    port = free_port()
    with Bus.router(port), Bus.client(port) as wb, Bus.client(port) as tb:
        worker = CellWorker(CELL, load_scenario("standing_beside_path"), wb, loop_task=False)
        sent: list[tuple[str, Any]] = []
        for name in ("verdict", "command"):  # record what the worker hands to zenoh
            pub = getattr(worker.io, name)
            real = pub.put

            def put(msg: Any, real: Any = real, name: str = name) -> bool:
                sent.append((name, msg))
                return real(msg)

            pub.put = put
        yield worker, tb, sent


@settings(
    max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(batch=st.lists(payloads(), min_size=1, max_size=6), frame=st.booleans())
def test_every_cycle_one_verdict_then_one_command(live, batch, frame) -> None:
    worker, tb, sent = live
    for hid, payload in batch:
        tb.session.put(keys.skeleton_key(CELL, hid), payload)
    time.sleep(0.003)  # let zenoh deliver (the worker never waits for input)
    for _ in range(3):
        now = time.time()
        if frame:
            worker.presence.frame("main", now, [])
        sent.clear()
        res = worker.step(now)
        assert [n for n, _ in sent] == ["verdict", "command"]
        verdict, command = sent[0][1], sent[1][1]
        assert isinstance(verdict, VerdictMsg) and isinstance(command, CommandArrays)
        assert isinstance(command.message(), RobotCommandMsg)  # the schema's validation
        assert verdict.mode == command.mode == res.mode
        assert all(np.isfinite(command.q)) and all(np.isfinite(command.q_dot))
        if command.mode == "intended":
            assert res.verified and not verdict.faults
            assert all(a <= worker.shield.settings.skeleton_timeout_s for a in
                       verdict.skeleton_age_s.values())  # fmt: skip
            assert not worker.presence.faults(now)
