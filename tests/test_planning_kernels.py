"""The compiled step planning (``PathFollower.peek``, :mod:`sara_app.robot.planning_kernels`)
equals its Python reference (``tests/planning_reference.py``) bit for bit, on states reached by
following random blended paths (speed caps, brakes before slower pieces and the path end,
replans, steps across piece starts) and on arbitrary path states (fallbacks when no step or stop
is valid); and the velocity-change phases both use keep their defining properties."""

from __future__ import annotations

import math

import numpy as np
import planning_reference
import pytest
from panda_limits import PANDA
from planning_reference import reference_peek
from profile_reference import phase_maxima, phases_end, velocity_phases

from sara_app.errors import RobotModelError
from sara_app.robot import planning_kernels as pk
from sara_app.robot import profile
from sara_app.robot.trajectory import _CONSTS, FollowerStep, PathFollower


def _bits(x: object) -> object:
    """Exact comparable form: floats by their hex digits (-0.0 and NaN payloads included)."""
    if isinstance(x, float):
        return x.hex()
    if isinstance(x, list | tuple):
        return [_bits(y) for y in x]
    return x


def _step_bits(st: FollowerStep) -> object:
    p, sp = st.profile, st.stop.profile
    fields = [st.dt, st.fallback, st.end, st.stop.A, st.stop.J, st.stop.duration_s]
    fields += [st.stop.s_start, st.stop.s_end]
    for prof in (p, sp):  # everything a profile holds (the compiled one gets its breaks given)
        fields += [prof.start, prof.end, prof.duration, prof.durs, prof.jerks]
        fields += [prof.tb_l, prof.sb_l, prof.vb_l, prof.ab_l]
    return _bits(fields)


def _same(f: PathFollower, dt: float) -> FollowerStep:
    fast, ref = f.peek(dt), reference_peek(f, dt)
    assert _step_bits(fast) == _step_bits(ref), (f.s, f.sd, f.sdd, f.speed_cap, dt)
    assert fast.path is ref.path is f.path
    return fast


def _follower(rng: np.random.Generator) -> PathFollower:
    W = int(rng.integers(2, 6))
    u = rng.uniform(0.15, 0.85, (W, 7))
    wps = PANDA.q_min + (PANDA.q_max - PANDA.q_min) * u
    return PathFollower(wps, PANDA, blend_distance=float(rng.uniform(0.01, 0.3)))


class _Count:
    def __init__(self) -> None:
        self.fit_brake = self.crossings = self.fallbacks = self.rest = 0

    def note(self, f: PathFollower, st: FollowerStep) -> None:
        starts = f.path._s0_list
        k0 = max(int(np.searchsorted(starts, f.s, side="right")) - 1, 0)
        k1 = max(int(np.searchsorted(starts, st.end[0], side="right")) - 1, 0)
        self.crossings += k1 != k0
        self.fallbacks += st.fallback
        self.rest += (not st.fallback) and st.stop.duration_s == 0.0


@pytest.fixture
def count(monkeypatch: pytest.MonkeyPatch) -> _Count:
    """Counts the reference's brakes fitted inside a step (the compiled bisection's cases)."""
    c = _Count()
    fit = planning_reference.fit_brake

    def counted(f: PathFollower, *args: object) -> object:
        c.fit_brake += 1
        return fit(f, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(planning_reference, "fit_brake", counted)
    return c


@pytest.mark.parametrize("seed", range(3))
def test_followed_paths_plan_alike(seed: int, count: _Count) -> None:
    rng = np.random.default_rng(seed)
    for _ in range(6):
        f = _follower(rng)
        dt = float(rng.choice([0.001, 0.004, 0.02]))
        replan_at = int(rng.integers(20, 120))
        for i in range(3000):
            if i % 17 == 0:  # caps: none, slower, a stop along the intended motion
                f.speed_cap = float(rng.choice([math.inf, rng.uniform(0.05, 1.5), 0.0]))
            st = _same(f, dt)
            count.note(f, st)
            f.brake(dt) if rng.random() < 0.05 else f.commit(st)
            if i == replan_at:
                f.replan(PANDA.q_min + (PANDA.q_max - PANDA.q_min) * rng.uniform(0.2, 0.8, (2, 7)))
            if f.done:
                count.note(f, _same(f, dt))
                break
    assert count.fit_brake > 0 and count.crossings > 0 and count.rest > 0


def test_arbitrary_states_plan_alike(count: _Count) -> None:
    """Any path state, reachable or not (too fast, accelerating hard, braking backwards, past
    the end): both plan the same step, stop or fallback."""
    rng = np.random.default_rng(11)
    for _ in range(10):
        f = _follower(rng)
        V_top, A_top = max(f._V), max(f._A)
        for _ in range(250):
            g = f.copy()
            g._s = float(rng.uniform(-1e-9, 1.0) * f.path.length)
            g._v = float(rng.choice([0.0, 1e-10, rng.uniform(0.0, 1.5 * V_top)]))
            g._a = float(rng.choice([0.0, rng.uniform(-2.0, 2.0) * A_top]))
            g.speed_cap = float(rng.choice([math.inf, rng.uniform(0.0, V_top)]))
            st = _same(g, float(rng.choice([0.001, 0.004, 0.02, 0.1])))
            count.note(g, st)
    assert count.fallbacks > 0 and count.fit_brake > 0 and count.crossings > 0


def test_velocity_phases_compiled_alike_and_sound() -> None:
    """The compiled velocity change equals ``velocity_phases`` bit for bit, and both reach the
    target speed at zero acceleration with positive durations, jerks of +-J (or a signed zero)
    and ``|s''|`` within ``max(A, |a0|)``."""
    rng = np.random.default_rng(5)
    special = [0.0, -0.0, 1e-300, 1.0, -1.0, 1e-12]
    for _ in range(20000):
        v0, a0, vt = (
            float(rng.choice(special)) if rng.random() < 0.15 else float(rng.uniform(-5, 5))
            for _ in range(3)
        )
        A, J = float(rng.uniform(0.1, 20.0)), float(rng.uniform(1.0, 5000.0))
        durs, jerks = velocity_phases(v0, a0, vt, A, J)
        ph = pk.velocity_phases_kernel(v0, a0, vt, A, J)
        n = int(ph[0])
        assert _bits([durs, jerks]) == _bits([list(ph[1 : 1 + n]), list(ph[4 : 4 + n])])
        assert all(t > 0.0 for t in durs) and all(abs(j) in (0.0, J) for j in jerks)
        _, v1, a1 = phases_end(0.0, v0, a0, durs, jerks)
        scale = 1.0 + abs(v0) + abs(vt) + a0 * a0 / J
        assert abs(v1 - vt) <= 1e-9 * scale and abs(a1) <= 1e-9 * (1.0 + abs(a0))
        assert phase_maxima(v0, a0, durs, jerks)[1] <= max(A, abs(a0)) * (1 + 1e-12)


def test_powers_as_python_computes_them() -> None:
    """Python's ``x ** 2`` and ``x ** 3`` of a float are the C library's ``pow``, which differs
    from ``x * x`` (``x * x * x``) in the last bit for some ``x``: at joint limits set exactly
    to what the reference's ``piece_ok`` computes for such ``x``, the kernel's test agrees with it
    where products would not."""
    rng = np.random.default_rng(3)
    odd = [x for x in rng.uniform(0.1, 10.0, 100000).tolist() if x**2 != x * x]
    assert len(odd) > 20
    pc = np.full((1, pk.PC_COLS), -1.0)  # the box test fails: the per-joint test decides
    pc[0, pk.S0] = 0.0
    flips = 0
    for vmax in odd[:200]:
        m1, m2, m3, amax, jmax = rng.uniform(0.1, 1.0, 5).tolist()
        lim_a = m2 * vmax**2 + m1 * amax  # numpy's M2 * vmax**2 + M1 * amax, one joint
        lim_j = m3 * vmax**3 + 3 * m2 * vmax * amax + m1 * jmax
        rows = np.array([[[m1, m2, m3, 1.0 / m1, 2.0 * m1 * vmax, lim_a, lim_j]]])
        assert pk._piece_ok(0, vmax, amax, jmax, pc, rows, _CONSTS)
        rows[0, 0, 5] = np.nextafter(lim_a, -np.inf)
        assert not pk._piece_ok(0, vmax, amax, jmax, pc, rows, _CONSTS)
        flips += m2 * (vmax * vmax) + m1 * amax != lim_a
    assert flips > 0  # with products the test would have decided otherwise


def test_non_finite_and_huge_states_plan_alike() -> None:
    """NaN, infinite and huge path states: the same step, fallback or error, except that
    Python's float power raises OverflowError for ``|s''| >~ 1e154`` where the compiled power
    returns inf (then no stop is valid: the follower falls back on the failsafe it holds)."""
    rng = np.random.default_rng(2)
    odd = [math.nan, math.inf, -math.inf, 1e300, -1e300, 1e-320, -0.0]
    overflows = 0
    for _ in range(300):
        g = _follower(rng)
        g._s = float(rng.choice([rng.uniform(0.0, g.path.length), *odd]))
        g._v = float(rng.choice([rng.uniform(0.0, 2.0), *odd]))
        g._a = float(rng.choice([rng.uniform(-5.0, 5.0), *odd]))
        g.speed_cap = float(rng.choice([math.inf, 0.5, 0.0]))
        out = []
        for peek in (g.peek, lambda dt, g=g: reference_peek(g, dt)):
            try:
                out.append(_step_bits(peek(0.004)))
            except Exception as e:  # noqa: BLE001 - compared, whatever it is
                out.append(type(e).__name__)
        if out[1] == "OverflowError":
            overflows += 1
            assert g.peek(0.004).fallback
        else:
            assert out[0] == out[1], (g.s, g.sd, g.sdd, g.speed_cap)
    assert overflows > 0


def test_the_profile_functions_are_the_compiled_ones_and_equal_the_python_reference() -> None:
    """``sara_app.robot.profile``'s phase functions run the planner's compiled helpers (one
    implementation); on random phase lists of up to 8 phases (a step) and times inside and
    after them they equal the plain Python reference bit for bit."""
    import profile_reference as ref

    rng = np.random.default_rng(12)
    for _ in range(3000):
        n = int(rng.integers(0, 9))
        durs = [float(x) for x in rng.uniform(1e-4, 0.05, n)]
        jerks = [float(x) for x in rng.choice([-900.0, 0.0, 450.0, 1e-3], n)]
        s, v, a = (float(x) for x in rng.normal(0, 1, 3))
        t = float(rng.uniform(0, 0.05 * n + 0.02))
        assert _bits([profile.phases_at(s, v, a, durs, jerks, t)]) == _bits(
            [ref.phases_at(s, v, a, durs, jerks, t)]
        )
        assert _bits([profile.phase_maxima(v, a, durs, jerks)]) == _bits(
            [ref.phase_maxima(v, a, durs, jerks)]
        )
        assert _bits(list(profile.cut_phases(durs, jerks, t))) == _bits(
            list(ref.cut_phases(durs, jerks, t))
        )
        if n <= 3:
            assert _bits([profile.phases_end(s, v, a, durs, jerks)]) == _bits(
                [ref.phases_end(s, v, a, durs, jerks)]
            )
        A, J = float(rng.uniform(0.1, 20.0)), float(rng.uniform(1.0, 5000.0))
        assert _bits(list(profile.velocity_phases(v, a, s, A, J))) == _bits(
            list(ref.velocity_phases(v, a, s, A, J))
        )


def test_a_step_from_a_reused_record_keeps_its_own_stop() -> None:
    """The shield reads each cycle's step from one record buffer that the next plan overwrites,
    and makes the step's profile and stop only when they are first read (the committed step's
    stop when a later cycle brakes): they are the step the record held, bit for bit, whatever
    the buffer holds by then, and the follower brakes along that stop."""
    rng = np.random.default_rng(5)
    record = np.empty(pk.OUT_LEN)
    checked = 0
    for _ in range(4):
        f = _follower(rng)
        dt = 0.004
        for i in range(400):
            if f.done:
                break
            s, v, a = f.s, f.sd, f.sdd
            status = pk.peek_kernel(
                s, v, a, dt, f._cap, f._S, f._A_min, f._J_min, f._ramp_c, *f._ktab, _CONSTS,
                record,
            )  # fmt: skip
            st = f.step_from_record(record, status, dt)
            if st.fallback:
                f.commit(st)
                continue
            expected = _step_bits(reference_peek(f, dt))
            moved = f.copy()
            moved._s += 1e-3  # the record's start is not this follower's state
            with pytest.raises(RobotModelError, match="planned for another path or state"):
                moved.commit(st)
            f.commit(st)
            record[:] = np.nan  # the next plan's record in the same buffer
            if i % 7 == 3:  # brake along the stop held: made now, from the step's own copy
                assert _step_bits(st) == expected
                held = f.stop
                assert held is st.stop
                f.brake(dt)
                checked += 1
    assert checked > 20
