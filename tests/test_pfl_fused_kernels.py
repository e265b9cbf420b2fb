"""The compiled PFL check (sara_app.safety.pfl_fused_kernels, run by the shield's compiled cycle)
against the Python composition of the same kernels in tests/pfl_reference.py: the same
verdicts, classes, thresholds, margins, link energies, model counts, model orders and commands,
bit for bit, cycle after cycle, for one person and for several."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from pfl_compare import (  # noqa: E402
    assert_same_cycle,
    bench_pair,
    make_pair,
    person_at,
    same_state_cycles,
)

from sara_app.geometry import shape_kernels
from sara_app.human import reach_kernels
from sara_app.human.widening import widening
from sara_app.kernel_types import source_digest
from sara_app.robot import crba_kernels, energy, occupancy_kernels
from sara_app.safety import contact_kernels, pfl_kernels, pfl_link_states
from sara_app.safety.pfl_fused_kernels import fused_kernel
from sara_app.safety.pfl_shield import PflCycle
from sara_app.safety.shield import HumanState


@pytest.mark.parametrize(
    ("models", "boxes"),
    [
        (("acc", "vel", "pos"), True),
        (("iso13855", "pos", "acc", "vel"), True),
        (("pos",), True),
        (("vel",), True),
        (("acc", "vel", "pos"), False),
        (("combined", "pos"), True),
    ],
)
def test_closed_loop_equals_the_python_composition(models: tuple[str, ...], boxes: bool) -> None:
    """A person walking up to the working robot, into reach and back out (clear, slowed and
    braking cycles, replans, lazy and finished checks, model-order changes), with noisy
    velocities and measurement ages, with and without a table: every cycle's outputs equal the
    reference's."""
    a, ref = make_pair(models, boxes)
    rng = np.random.default_rng(len(models))
    t = 0.0
    for _ in range(30):  # nobody: the robot speeds up
        assert_same_cycle(a, a.cycle(t, []), ref, ref.cycle(t, []))
        t += a.settings.dt_s
    xy = np.array([1.6, -0.6])
    goal = np.array([0.55, -0.35])
    modes = set()
    checks = set()
    for n in range(260):
        if n == 160:
            goal = np.array([1.6, 0.4])
        step = 0.006 * (goal - xy) / max(np.linalg.norm(goal - xy), 1e-9)
        xy = xy + step + rng.normal(0.0, 0.002, 2)
        v = np.append(step / a.settings.dt_s, 0.0) + rng.normal(0.0, 0.2, 3)
        people = [person_at(xy, v, 0.05 + 0.1 * rng.random(), t - rng.uniform(0.0, 0.02))]
        ra, rr = a.cycle(t, people), ref.cycle(t, people)
        assert_same_cycle(a, ra, ref, rr)
        modes.add(ra.mode)
        if isinstance(a._res, PflCycle):
            checks.add(a._res.checks)
        t += a.settings.dt_s
    assert "intended" in modes and checks >= {1}  # the episode is what it says
    if models == ("acc", "vel", "pos") and boxes:
        assert "failsafe" in modes and 2 in checks


@pytest.mark.parametrize("case", ["clear", "slowed", "braking"])
def test_benchmark_states_equal_the_python_composition(case: str) -> None:
    """The benchmark's three states, each from full speed (a failed check at full speed
    first), with the model order the reference learns over repeated cycles."""
    shield, ref, template, people, t = bench_pair(case)
    same_state_cycles(shield, ref, template, people, t, 4)


@pytest.mark.parametrize("bad", ["v", "dv", "stamp"])
def test_non_finite_person_inputs_equal_the_reference(bad: str) -> None:
    """A NaN velocity or velocity bound (accepted by the shield: NaN capsules mean contact
    everywhere) or an old measurement: the same cycle as the reference, and nothing unproved
    is committed."""
    a, b = make_pair(("acc", "vel", "pos"))
    t = 0.0
    for _ in range(40):
        a.cycle(t, [])
        b.cycle(t, [])
        t += a.settings.dt_s
    xy, v = np.array([0.9, -0.4]), np.zeros(3)
    p = person_at(xy, v, 0.05, t - 0.01)
    if bad == "v":
        p.v[3] = np.nan
    elif bad == "dv":
        p.dv[5] = np.nan
    else:
        p = person_at(xy, v, 0.05, t - 0.5)
    ra, rb = a.cycle(t, [p]), b.cycle(t, [p])
    assert_same_cycle(a, ra, b, rb)
    assert ra.verified == (ra.pfl is not None and ra.pfl.safe_all)


def test_cache_key_carries_the_callees_sources() -> None:
    """Numba's cache checks only the kernel's own file: the closure (hashed into the cache
    key) holds the source digests of every file whose kernels it calls."""
    cells = [c.cell_contents for c in fused_kernel.py_func.__closure__ or ()]
    text = "".join(c for c in cells if isinstance(c, str))
    for module in (
        shape_kernels, reach_kernels, crba_kernels, energy, occupancy_kernels,
        contact_kernels, pfl_kernels, pfl_link_states,
    ):  # fmt: skip
        assert source_digest(module) in text, module.__name__


def _contacts_walking_in(
    dress: Callable[[HumanState], None], dress_plain: Callable[[HumanState], None]
) -> tuple[int, int]:
    """A person walking into reach of the working robot, ``dress``-ed (a widening, a height
    bound) for the compiled check and its reference, which must agree cycle by cycle, and
    ``dress_plain``-ed for a third shield: the possible contacts ((interval, link, part)
    triples) over the episode, ``(dressed, plain)``."""
    a, ref = make_pair(("acc", "vel", "pos"))
    plain = make_pair(("acc", "vel", "pos"))[0]
    t = 0.0
    for _ in range(30):
        for s in (a, ref, plain):
            s.cycle(t, [])
        t += a.settings.dt_s
    xy, goal = np.array([1.3, -0.5]), np.array([0.5, -0.3])
    contacts = [0, 0]
    for _ in range(200):
        step = 0.006 * (goal - xy) / max(np.linalg.norm(goal - xy), 1e-9)
        xy = xy + step
        v = np.append(step / a.settings.dt_s, 0.0)
        p, q = person_at(xy, v, 0.1, t - 0.01), person_at(xy, v, 0.1, t - 0.01)
        dress(p)
        dress_plain(q)
        ra, rr = a.cycle(t, [p]), ref.cycle(t, [p])
        assert_same_cycle(a, ra, ref, rr)
        rp = plain.cycle(t, [q])
        for i, r in enumerate((ra, rp)):
            contacts[i] += 0 if r.pfl is None else int(r.pfl.contact.contact.sum())
        t += a.settings.dt_s
    return contacts[0], contacts[1]


@pytest.mark.parametrize(("extra_m", "legs"), [(0.03, True), (0.0, False), (0.02, False)])
def test_widened_people_equal_the_python_composition(extra_m: float, legs: bool) -> None:
    """A person measured less precisely (a stated uncertainty above the parameter set's) or
    without legs (an upper-body source), walking into reach: the compiled check widens the sets
    exactly as the reference does, cycle by cycle; and the wider sets reach the robot sooner
    (more possible contacts over the episode than for the same person measured plainly)."""
    widen = widening(make_pair(("acc", "vel", "pos"))[0].reach, extra_m, legs_measured=legs)
    assert widen is not None

    def widened(p: HumanState) -> None:
        p.widen_m = widen

    dressed, plain = _contacts_walking_in(widened, lambda p: None)
    assert dressed > plain, (dressed, plain)


@pytest.mark.parametrize("base_m", [0.0, 0.3])
def test_height_bounded_legs_equal_the_python_composition(base_m: float) -> None:
    """A person seen by an upper-body tracker (legs widened by their reach) whose legs are
    bounded from above (``leg_cap``: the legs' parts below ``base_m`` + 0.5 m/s since the
    measurement), walking into reach: every cycle equals the reference's, and the bound leaves
    fewer possible contacts than the same person without it."""
    from sara_app.human.params import LEG_PARTS

    reach = make_pair(("acc", "vel", "pos"))[0].reach
    widen = widening(reach, 0.0, legs_measured=False)
    caps = np.zeros((reach.skeleton.n_parts, 2))
    caps[:, 0] = np.inf
    for q in LEG_PARTS:
        caps[reach.skeleton.parts.index(q)] = (base_m, 0.5)

    def bounded(p: HumanState) -> None:
        p.widen_m, p.leg_cap = widen, caps

    def unbounded(p: HumanState) -> None:
        p.widen_m = widen

    dressed, plain = _contacts_walking_in(bounded, unbounded)
    assert dressed < plain, (dressed, plain)


@pytest.mark.parametrize("H", [2, 4, 8])
def test_several_people_equal_the_python_composition(H: int) -> None:
    """``H`` people walking at the working robot from different sides at different speeds,
    with their own measurement ages and noisy velocities, some of them widened, two of them
    close together (multi-body clamping between people): every cycle equals the reference's,
    which classifies with a check built from the people's ``human_index``."""
    a, ref = make_pair(("acc", "vel", "pos"))
    rng = np.random.default_rng(H)
    widen = widening(a.reach, 0.02, legs_measured=True)
    t = 0.0
    for _ in range(30):
        assert_same_cycle(a, a.cycle(t, []), ref, ref.cycle(t, []))
        t += a.settings.dt_s
    angles = np.linspace(-1.2, 1.2, H)
    starts = np.stack([1.5 * np.cos(angles), 1.5 * np.sin(angles)], axis=1)
    goals = np.stack([0.6 * np.cos(angles), 0.6 * np.sin(angles) - 0.2], axis=1)
    starts[-1] = starts[0] + [0.05, 0.3]  # the last one beside the first
    goals[-1] = goals[0] + [0.05, 0.25]
    xy = starts.copy()
    speed = rng.uniform(0.004, 0.008, H)
    modes, checks = set(), set()
    for _ in range(160):
        people = []
        for h in range(H):
            step = speed[h] * (goals[h] - xy[h]) / max(np.linalg.norm(goals[h] - xy[h]), 1e-9)
            xy[h] = xy[h] + step + rng.normal(0.0, 0.002, 2)
            v = np.append(step / a.settings.dt_s, 0.0) + rng.normal(0.0, 0.2, 3)
            p = person_at(xy[h], v, 0.05 + 0.1 * rng.random(), t - rng.uniform(0.0, 0.03), f"p{h}")
            if h % 3 == 1:
                p.widen_m = widen
            people.append(p)
        ra, rr = a.cycle(t, people), ref.cycle(t, people)
        assert_same_cycle(a, ra, ref, rr)
        modes.add(ra.mode)
        if isinstance(a._res, PflCycle):
            checks.add(a._res.checks)
            if ra.pfl is not None:
                assert ra.pfl.safe.shape[2] == H * a.reach.skeleton.n_parts
        t += a.settings.dt_s
    assert {"intended", "failsafe"} <= modes and 2 in checks, (modes, checks)
