"""Switching a live cell worker between SSM, PFL and JSSA: the robot keeps its state across
every switch, the verdicts name the mode in force, and leaving JSSA (which holds no verified
failsafe) waits for the robot to be at rest (refused with the reason, nothing half-applied)."""

from __future__ import annotations

import numpy as np
import pytest

from sara_app.bus import keys
from sara_app.bus.messages import OccupancyMsg, VerdictMsg
from sara_app.bus.session import Bus, free_port
from sara_app.runtime.worker import CellWorker
from sara_app.scenario import load_scenario

# live cells whose rates and timings the assertions read: no other test runs beside them
pytestmark = [pytest.mark.exclusive, pytest.mark.usefixtures("idle_cpus_poll")]


@pytest.fixture()
def worker():
    port = free_port()
    with Bus.router(port) as hub, Bus.client(port) as wb:
        w = CellWorker("modes", load_scenario("standing_beside_path"), wb, loop_task=False)
        sub = hub.subscribe(keys.verdict_key("modes"), fifo=True, capacity=10000)
        yield w, sub


def _with_mode(w: CellWorker, mode: str) -> dict:
    data = w.cell.scenario.model_dump(mode="json")
    data["shield"]["mode"] = mode
    return data


def _run(w: CellWorker, t: float, n: int) -> float:
    for _ in range(n):
        w.presence.frame("main", t, [])  # the tracker sees nobody
        w.step(t)
        t += w.shield.settings.dt_s
    return t


def test_modes_switch_live_and_keep_the_robot_state(worker) -> None:
    w, verdicts = worker
    t = _run(w, 1000.0, 100)
    assert np.max(np.abs(w.shield.robot_state.v)) > 0.05  # moving when we switch
    follower = w.shield.follower
    q_before = w.shield.robot_state.q.copy()

    ok, why = w.apply(_with_mode(w, "pfl"))
    assert ok, why
    assert w.shield.safety_mode == "pfl" and w.shield.follower is follower  # same failsafe
    np.testing.assert_array_equal(w.shield.robot_state.q, q_before)
    t = _run(w, t, 20)
    assert w.last is not None and w.last.safety_mode == "pfl" and w.last.pfl is None  # nobody

    q_before = w.shield.robot_state.q.copy()
    ok, why = w.apply(_with_mode(w, "jssa"))
    assert ok, why
    assert w.shield.safety_mode == "jssa"
    np.testing.assert_array_equal(w.shield.robot_state.q, q_before)
    t = _run(w, t, 20)
    assert w.last is not None and w.last.safety_mode == "jssa" and w.last.jssa is not None
    occ = w.occupancy_msg(t, w.last)
    assert isinstance(occ, OccupancyMsg) and occ.jssa is not None and not occ.jssa.active

    # JSSA verified nothing: even on the path, leaving it while moving waits for rest
    ok, why = w.apply(_with_mode(w, "ssm"))
    assert not ok and "at rest" in why and w.shield.safety_mode == "jssa"
    t = _run(w, t, 5)
    # pushed off the path (as JSSA does near people): the same, then SSM starts where it rests
    w.shield._q = w.shield._q + 2e-3  # type: ignore[attr-defined]
    ok, why = w.apply(_with_mode(w, "ssm"))
    assert not ok and "at rest" in why and w.shield.safety_mode == "jssa"
    for _ in range(5000):
        t = _run(w, t, 1)
        if w.shield.at_rest and w.shield.task_done:
            break
    assert w.shield.at_rest
    q_rest = w.shield.robot_state.q.copy()
    ok, why = w.apply(_with_mode(w, "ssm"))
    assert ok, why
    np.testing.assert_allclose(w.shield.robot_state.q, q_rest, atol=1e-9)
    assert w.shield.safety_mode == "ssm"
    t = _run(w, t, 5)
    assert w.last is not None and w.last.safety_mode == "ssm" and w.last.mode != "fault"
    seen = {d.msg.safety_mode for d in verdicts.drain().messages if isinstance(d.msg, VerdictMsg)}
    assert {"pfl", "jssa"} <= seen


def test_pfl_display_shows_link_energies_the_check_skipped(worker) -> None:
    """With nobody able to touch the robot the PFL check skips the link energies; the display
    message still carries each link's energy (computed for it, equal to the check's own)."""
    import math

    from sara_app.human.scripted import joints, standing
    from sara_app.safety.shield import HumanState

    w, _ = worker
    ok, why = w.apply(_with_mode(w, "pfl"))
    assert ok, why
    t = _run(w, 1000.0, 100)
    y = joints(standing((12.0, 9.0), math.pi))  # out of reach of every shipped set (15 m)
    far = HumanState("far", y, np.zeros_like(y), np.full(len(y), 0.05), t - 0.004)
    res = w.shield.cycle(t, [far])
    assert res.pfl is not None and not res.pfl.energy_known and res.trajectory is not None
    occ = w.occupancy_msg(t, res)
    assert occ.links is not None and len(occ.links) == len(w.cell.robot.link_names)
    E = w.shield.with_energies(res.pfl, res.trajectory).energy_J  # type: ignore[attr-defined]
    got = np.array([m.energy_j for m in occ.links])
    np.testing.assert_allclose(got, E.max(axis=0))
    assert got.max() > 0.0 and all(m.limit_j is None for m in occ.links)  # moving, no contact


def test_leaving_jssa_over_the_bus_brakes_to_rest_then_switches() -> None:
    """An editor asks a moving JSSA cell for SSM (the dashboard's dropdown, the API's PATCH):
    the worker halts JSSA (braking verdicts, no intended step), switches at rest and only then
    answers 'accepted'."""
    import threading
    import time

    from sara_app.api.registry import CellRegistry
    from sara_app.bus.heartbeat import Heartbeat

    port = free_port()
    with Bus.router(port), Bus.client(port) as wb, Bus.client(port) as tb, \
            CellRegistry.connect(port) as reg:  # fmt: skip
        w = CellWorker("modes", load_scenario("standing_beside_path"), wb)
        sub = tb.subscribe(keys.verdict_key("modes"), fifo=True, capacity=20000)
        thread = threading.Thread(target=w.run, daemon=True)
        thread.start()
        try:
            with Heartbeat(tb, "modes"):
                assert reg.request_params("modes", _with_mode(w, "jssa"), 20.0).accepted
                time.sleep(0.8)
                assert w.shield.safety_mode == "jssa" and not w.shield.at_rest  # moving
                sub.drain()
                ans = reg.request_params("modes", _with_mode(w, "ssm"), 20.0)
                assert ans.accepted, ans.reason
                assert w.shield.safety_mode == "ssm"
                got = [d.msg for d in sub.drain().messages if isinstance(d.msg, VerdictMsg)]
        finally:
            w.stop_event.set()
            thread.join(10)
    jssa = [v for v in got if v.safety_mode == "jssa"]
    assert len(jssa) > 10  # it braked for a while
    first = next(i for i, v in enumerate(jssa) if v.mode == "failsafe")  # halted from here
    assert first < 50 and all(v.mode != "intended" for v in jssa[first:])
    assert jssa[-1].mode in ("rest", "failsafe")
