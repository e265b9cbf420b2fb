"""Cycle-by-cycle comparison of PFL shields (the compiled cycle against the reference) and the
cells and people they run on."""

from __future__ import annotations

import math
from dataclasses import fields
from typing import Any, cast

import numpy as np
from pfl_reference import as_reference

from sara_app.cell.build import build_cell
from sara_app.human.scripted import joints, standing
from sara_app.safety.pfl import PflResult
from sara_app.safety.pfl_shield import PflCycle, PflShield
from sara_app.safety.shield import CycleResult, HumanState
from sara_app.scenario import parse_scenario

TABLE = {"name": "table", "center_m": [0.65, 0.0, 0.1], "size_m": [0.5, 1.6, 0.2]}
Q = [0.3, 0.0, -1.8, 0.0, 2.1, 0.8]


def assert_same_result(a: PflResult | None, b: PflResult | None) -> None:
    assert (a is None) == (b is None)
    if a is None or b is None:
        return
    for f in fields(PflResult):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name == "contact":
            for g in fields(x):
                np.testing.assert_array_equal(getattr(x, g.name), getattr(y, g.name), g.name)
        else:
            np.testing.assert_array_equal(x, y, err_msg=f.name)  # NaN equals NaN here


def assert_same_cycle(sa: PflShield, ra: CycleResult, sb: PflShield, rb: CycleResult) -> None:
    assert (ra.mode, ra.verified, ra.faults) == (rb.mode, rb.verified, rb.faults)
    np.testing.assert_array_equal(ra.command.q, rb.command.q)
    np.testing.assert_array_equal(ra.command.v, rb.command.v)
    assert ra.speed_scale == rb.speed_scale
    assert_same_result(ra.pfl, rb.pfl)
    assert_same_trajectory(ra, rb)
    ia, ib = sa._res, sb._res
    if isinstance(ia, PflCycle) and isinstance(ib, PflCycle):
        assert (ia.cap, ia.speed_scale, ia.checks, ia.models_used, ia.evaluations) == (
            ib.cap, ib.speed_scale, ib.checks, ib.models_used, ib.evaluations
        )  # fmt: skip
    assert (sa.cap, sa._calm, sa._orders) == (sb.cap, sb._calm, sb._orders)


def assert_same_trajectory(ra: CycleResult, rb: CycleResult) -> None:
    """The checked trajectories, their steps and failsafes and their robot capsules."""
    ta, tb = ra.trajectory, rb.trajectory
    assert (ta is None) == (tb is None)
    if ta is None or tb is None:
        return
    for name in ("times", "q", "v", "a", "s", "sd", "sdd", "v_bound", "a_bound", "dq", "sd_max"):
        np.testing.assert_array_equal(getattr(ta, name), getattr(tb, name), err_msg=name)
    sa, sb = ta.step, tb.step
    assert (sa.dt, sa.end, sa.fallback) == (sb.dt, sb.end, sb.fallback)
    for pa, pb in ((sa.profile, sb.profile), (sa.stop.profile, sb.stop.profile)):
        assert (pa.durs, pa.jerks, pa.start, pa.end) == (pb.durs, pb.jerks, pb.start, pb.end)
    assert (sa.stop.A, sa.stop.J, sa.stop.duration_s) == (sb.stop.A, sb.stop.J, sb.stop.duration_s)
    np.testing.assert_array_equal(ra.robot_ends, rb.robot_ends)
    np.testing.assert_array_equal(ra.robot_radius, rb.robot_radius)


def make_pair(models: tuple[str, ...], boxes: bool = True) -> tuple[PflShield, PflShield]:
    """Two identical PFL cells: the production shield and its reference
    (:class:`pfl_reference.ReferencePflShield`)."""
    sc = parse_scenario(
        {
            "name": "t",
            "task": {"waypoints_rad": [[-1.2, *Q], [1.2, *Q]]},
            "environment": [TABLE] if boxes else [],
            "shield": {"mode": "pfl", "models": list(models)},
            "human_params": "schepp2022_table1",  # the people of these tests walk for its sets
        }
    )
    cells = [build_cell(sc).shield for _ in range(2)]
    assert all(isinstance(c, PflShield) for c in cells)
    a, ref = cast(list[PflShield], cells)
    return a, as_reference(ref)


def person_at(xy: np.ndarray, v: np.ndarray, dv: float, stamp: float, hid: str = "p") -> HumanState:
    yj = joints(standing((float(xy[0]), float(xy[1])), math.atan2(-xy[1], -xy[0])))
    return HumanState(hid, yj, np.broadcast_to(v, yj.shape).copy(), np.full(len(yj), dv), stamp)


def bench_pair(case: str) -> tuple[PflShield, PflShield, Any, list[HumanState], float]:
    """The benchmark cell in state ``case`` (``bench.pfl.BENCH_CASES``) and its reference:
    ``(shield, ref, template, people, t)``."""
    from sara_app.bench.pfl import BENCH_CASES, shield_cell

    shield, template, people, t = shield_cell(BENCH_CASES[case])
    ref = as_reference(shield_cell(BENCH_CASES[case])[0])
    return shield, ref, template, people, t


def same_state_cycles(
    shield: PflShield, ref: PflShield, template: Any, people: list[HumanState], t: float, n: int
) -> list[object]:
    """``n`` cycles of both shields, each from the follower ``template`` at full speed (as in
    the benchmark), compared cycle by cycle; returns the shield's ``_res`` of each."""
    infos = []
    for _ in range(n):
        for s in (shield, ref):
            s.follower = template.copy()
            s.cap, s._calm = math.inf, 0
        a = shield.cycle(t, people, want_distance=False)
        b = ref.cycle(t, people, want_distance=False)
        assert_same_cycle(shield, a, ref, b)
        infos.append(shield._res)
    return infos
