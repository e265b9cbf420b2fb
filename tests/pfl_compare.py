"""Cycle-by-cycle comparison of two PFL shields (the compiled paths against the reference)."""

from __future__ import annotations

from dataclasses import fields

import numpy as np

from sara_app.safety.pfl import PflResult
from sara_app.safety.pfl_shield import PflCycle, PflShield
from sara_app.safety.shield import CycleResult


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
