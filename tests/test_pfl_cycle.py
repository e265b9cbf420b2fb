"""The compiled PFL cycle (sara_app.safety.pfl_cycle): its plan slab layout, a follower with
nothing ahead, a kernel failure, what it refuses, its constants for several people and its
cache key. Its equality with the Python reference, cycle by cycle, is in
tests/test_pfl_fused_kernels.py."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pfl_compare import (  # noqa: E402
    assert_same_cycle,
    bench_pair,
    make_pair,
    person_at,
    same_state_cycles,
)

from sara_app.bench.pfl import BENCH_CASES, shield_cell
from sara_app.errors import ParameterError
from sara_app.geometry import shape_kernels
from sara_app.human import reach_kernels
from sara_app.kernel_types import source_digest
from sara_app.robot import (
    crba_kernels,
    energy,
    occupancy_kernels,
    planning_kernels,
    shielded_kernels,
    trajectory_kernels,
)
from sara_app.safety import contact_kernels, pfl_fused_kernels, pfl_kernels, pfl_link_states
from sara_app.safety import pfl_cycle as pfl_cycle_module
from sara_app.safety.pfl import PflCheck
from sara_app.safety.pfl_cycle import CompiledCycle
from sara_app.safety.pfl_cycle_kernels import BAIL, cycle_kernel
from sara_app.safety.pfl_shield import PflCycle


def test_a_follower_with_nothing_ahead_is_checked_without_replans(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A follower the kernel cannot plan for (done, or a path without pieces): its trajectory
    is checked with every model and no replan, as the reference does."""
    shield, ref, template, people, t = bench_pair("braking")
    monkeypatch.setattr(type(template), "kernel_state", lambda self, dt: None)
    for info in same_state_cycles(shield, ref, template, people, t, 3):
        assert isinstance(info, PflCycle) and info.checks == 1


def test_a_kernel_failure_is_a_fault(monkeypatch: pytest.MonkeyPatch) -> None:
    """A check that ends in a state a classification cannot produce: the cycle is a fault
    (the robot brakes on its held failsafe), not an exception and not a verified step."""
    shield, template, people, t = shield_cell(BENCH_CASES["clear"])

    def bail(*args: object) -> tuple:
        return BAIL, np.empty(0), ()

    monkeypatch.setattr(pfl_cycle_module, "cycle_kernel", bail)
    res = shield.cycle(t, people, want_distance=False)
    assert res.mode == "fault" and not res.verified
    assert any("no link energies" in f for f in res.faults)


@pytest.mark.parametrize("case", ["slowed", "braking"])
def test_the_compiled_loop_runs_the_two_check_cycles(case: str) -> None:
    """In the benchmark's slowed and braking states the compiled loop runs both checks (no
    hand-over) and returns the replan's trajectory, step and capsules."""
    shield, template, people, t = shield_cell(BENCH_CASES[case])
    compiled = shield.compiled
    runs = []
    real = compiled.run

    def counted(*a: object, **k: object) -> object:
        out = real(*a, **k)  # type: ignore[arg-type]
        runs.append(out)
        return out

    compiled.run = counted  # type: ignore[method-assign, assignment]
    shield.follower = template.copy()
    shield.cap = math.inf
    res = shield.cycle(t, people, want_distance=False)
    out = runs[-1]
    assert out.checks == 2
    assert res.trajectory is out.traj and res.robot_ends is out.ends
    assert out.traj.step.profile.start == (template.s, template.sd, template.sdd)
    assert out.ends.shape[0] == len(out.traj.times) - 1 == out.result.safe.shape[0]


def test_construction_is_validated() -> None:
    """Times and a model the kernel does not compute are refused when the shield is built,
    each with the reason (a robot without the compiled CRBA is refused by its link states:
    tests/test_crba.py)."""
    shield = shield_cell(BENCH_CASES["clear"])[0]
    s = shield.settings
    args = (shield.pfl, shield._link_states, shield.verifier.reach)
    rest = (shield.boxes, shield.occupancy, shield.tracking_margin_m)
    for dt, max_interval in ((0.004, 0.0), (0.0, 0.02), (0.004, math.nan)):
        with pytest.raises(ParameterError, match="expected times > 0"):
            CompiledCycle(*args, s.models, *rest, dt, max_interval)
    with pytest.raises(ParameterError, match="'arm' is not available in PFL mode; valid: acc"):
        CompiledCycle(*args, ("vel", "arm"), *rest, s.dt_s, s.max_interval_s)


@pytest.mark.parametrize("H", [1, 2, 3, 8])
def test_constants_for_several_people_equal_a_check_of_their_parts(H: int) -> None:
    """The classification's constants for ``H`` people, tiled from one person's, equal those
    of a :class:`PflCheck` built from the ``H`` people's parts and their ``human_index``."""
    shield = shield_cell(BENCH_CASES["clear"])[0]
    parts = shield.reach.skeleton.parts
    ref = PflCheck(
        shield.robot, parts * H, thresholds=shield.thresholds,
        link_shapes=shield.spec.link_shapes, human_index=np.repeat(np.arange(H), len(parts)),
    )  # fmt: skip
    want = (*ref.classifier.kernel_arrays(), ref.T_clamp, ref.T_free)
    got = shield.compiled.constants_for(H)[0]
    assert len(got) == len(want) == 5
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g, w)


def test_cache_key_carries_the_callees_sources() -> None:
    """Numba's cache checks only the kernel's own file: the closure (hashed into the cache
    key) holds the source digests of every file whose kernels it calls."""
    cells = [c.cell_contents for c in cycle_kernel.py_func.__closure__ or ()]
    text = "".join(c for c in cells if isinstance(c, str))
    for module in (
        shape_kernels, reach_kernels, crba_kernels, energy, occupancy_kernels,
        planning_kernels, trajectory_kernels, shielded_kernels, contact_kernels, pfl_kernels,
        pfl_link_states, pfl_fused_kernels,
    ):  # fmt: skip
        assert source_digest(module) in text, module.__name__


def test_the_warm_up_at_construction_leaves_the_shield_as_it_was() -> None:
    """The shield runs one compiled cycle when it is built (its first call resolves the
    argument types); afterwards its orders, cap and follower are those of a fresh shield, and
    its first cycles equal the reference's."""
    a, ref = make_pair(("acc", "vel", "pos"))
    assert a._orders == (["acc", "vel", "pos"], ["acc", "vel", "pos"]) == ref._orders
    assert (a.cap, a._calm) == (math.inf, 0)
    assert (a.follower.s, a.follower.sd, a.follower.sdd) == (0.0, 0.0, 0.0)
    t = 0.0
    for _ in range(40):
        assert_same_cycle(a, a.cycle(t, []), ref, ref.cycle(t, []))
        t += a.settings.dt_s
    p = person_at(np.array([0.9, -0.4]), np.zeros(3), 0.05, t - 0.01)
    assert_same_cycle(a, a.cycle(t, [p]), ref, ref.cycle(t, [p]))
