"""Containment on recordings as they come: jittered time stamps are analysed on their real
times, and a model without a velocity estimate is reported unavailable, never checked with a
made-up set."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from sara_app.human.analysis import containment, occupancies
from sara_app.human.params import load_param_set, to_reach_params
from sara_app.human.reach import HumanReach
from sara_app.human.recordings import load_recording

SPEED = 1.9  # m/s, below Table I's 2.0 for every joint


def _jittered(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A rigid skeleton moving at SPEED along x, stamped by a 60 Hz tracker in milliseconds
    with up to 4 ms of jitter: times ``(T,)`` and joints ``(T, 15, 3)`` exact at those times."""
    rng = np.random.default_rng(seed)
    nominal = np.arange(120) / 60.0
    t = np.round(nominal + rng.uniform(-0.004, 0.004, nominal.shape), 3)
    pose = load_recording("02_01").positions_m[0]
    return t, pose[None] + (SPEED * t)[:, None, None] * np.array([1.0, 0.0, 0.0])


@pytest.mark.parametrize("seed", range(3))
def test_jittered_stamps_are_analysed_on_their_real_times(seed: int) -> None:
    t, y = _jittered(seed)
    assert np.ptp(np.diff(t)) > 0.004  # really jittered
    exact = to_reach_params(load_param_set("schepp2022_table1"), "full")
    exact = replace(exact, delta_y_m=0.0)
    res = containment(HumanReach(exact), t, y, 0.3, ("vel", "acc", "combined"))
    for m in ("vel", "acc", "combined"):  # 1.9 m/s within 2.0 at every real time difference
        assert res[m].share == 1.0, (m, res[m].worst[:2])
    slow = replace(exact, v_max_mps=np.full(15, 1.85))
    res = containment(HumanReach(slow), t, y, 0.3, ("vel",))
    # beyond the bound by 0.05 m/s: every pair more than (half thickness margin) apart misses
    assert res["vel"].share < 1.0
    worst = res["vel"].worst[0]
    assert worst.excess_m == pytest.approx(0.05 * worst.dt_s, abs=1e-9)
    i = int(np.flatnonzero(t == worst.t_s)[0])
    assert any(np.isclose(t[i + k] - t[i], worst.dt_s, atol=1e-12) for k in range(1, 30))


def test_a_model_without_a_velocity_estimate_is_unavailable() -> None:
    t, y = _jittered(0)
    reach = HumanReach(to_reach_params(load_param_set("schepp2022_table1"), "full"))
    occ = occupancies(reach, t, y, np.zeros(1), np.array([0.2]), ("acc", "combined"))
    assert np.isinf(occ["acc"].radius[0]).all()  # the first frame: no estimate
    assert np.isfinite(occ["acc"].radius[1:]).all() and (occ["acc"].radius[1:] < 10).all()
    assert np.isfinite(occ["combined"].radius).all()  # falls back on the speed ball
    res = containment(reach, t, y, 0.3, ("acc",))
    K = res["acc"].unavailable // 15
    assert res["acc"].unavailable == 15 * K > 0  # the first frame's future, every joint
    assert res["acc"].checked + res["acc"].unavailable == sum(
        15 * int(((t > ti) & (t <= ti + 0.3 + 1e-12)).sum()) for ti in t
    )


def test_the_effective_set_contains_a_position_only_when_every_model_in_use_does() -> None:
    """A brute-force check of the effective set's misses from each model's: a position missed
    by any model in use is missed by the effective set (the verdict clears a body part when ANY
    model's set for it is free), the models not in use do not count, and the misses at frames
    the monitor had faulted the person for are not unflagged."""
    t, y = _jittered(1)
    exact = replace(to_reach_params(load_param_set("schepp2022_table1"), "full"), delta_y_m=0.0)
    v = np.full(15, 2.0)
    v[7] = 1.85  # only the vel model's l_wrist bound is too slow (1.9 m/s motion)
    reach = HumanReach(replace(exact, v_max_mps=v))
    models = ("pos", "vel", "acc")
    res = containment(reach, t, y, 0.3, models)
    eff = res["effective"]
    assert all(res[m].contained == res[m].checked for m in ("pos", "acc"))  # these hold
    vel_misses = res["vel"].checked - res["vel"].contained
    assert vel_misses > 0 and eff.checked - eff.contained == vel_misses  # vel's misses only
    assert eff.misses_per_joint == res["vel"].misses_per_joint == {"l_wrist": vel_misses}
    assert eff.unflagged is None  # not screened
    without_vel = containment(reach, t, y, 0.3, models, effective_of=("pos", "acc"))
    assert without_vel["effective"].contained == without_vel["effective"].checked
    misses = eff.checked - eff.contained
    none = containment(reach, t, y, 0.3, models, faulted=np.zeros(len(t), bool))["effective"]
    every = containment(reach, t, y, 0.3, models, faulted=np.ones(len(t), bool))["effective"]
    assert (none.unflagged, every.unflagged) == (misses, 0)
    first = np.zeros(len(t), bool)
    first[: len(t) // 2] = True  # faulted in the first half only
    half = containment(reach, t, y, 0.3, models, faulted=first)["effective"]
    assert 0 < half.unflagged < misses  # the uniform motion misses in both halves


def _tight_uniform() -> tuple[HumanReach, np.ndarray, np.ndarray]:
    """Two seconds of a CMU walk at its own 120 Hz (uniform stamps) and a set too slow for it,
    so every model misses somewhere."""
    rec = load_recording("02_01")
    p = to_reach_params(load_param_set("schepp2022_table1"), "full")
    slow = replace(p, v_max_mps=np.full(15, 1.0), iso_v_max_mps=1.0)
    return HumanReach(slow), rec.times_s[:240], rec.positions_m[:240]


@pytest.mark.parametrize("pairs", [1, 37, 1000])
def test_chunking_does_not_change_the_result(pairs: int) -> None:
    """Frames analysed in chunks (one frame, an odd number, a few hundred) give the very counts,
    misses per joint, unflagged misses and worst escapes of one piece, on uniform and jittered
    stamps (the two ways the sets are built)."""
    faulted = np.zeros(240, bool)
    faulted[50:90] = True
    for reach, t, y, f in (
        (*_tight_uniform(), faulted),
        (HumanReach(replace(to_reach_params(load_param_set("schepp2022_table1"), "full"),
                            v_max_mps=np.full(15, 1.85))), *_jittered(2), faulted[:120]),
    ):  # fmt: skip
        whole = containment(reach, t, y, 0.3, faulted=f, n_worst=8, pairs_per_chunk=10**9)
        chunked = containment(reach, t, y, 0.3, faulted=f, n_worst=8, pairs_per_chunk=pairs)
        assert whole.keys() == chunked.keys()
        assert any(r.contained < r.checked for r in whole.values())  # misses to merge
        for m, r in whole.items():
            c = chunked[m]
            assert (c.checked, c.contained, c.unavailable, c.unflagged) == (
                r.checked, r.contained, r.unavailable, r.unflagged)  # fmt: skip
            assert c.misses_per_joint == r.misses_per_joint
            assert list(c.misses_per_joint) == list(r.misses_per_joint)  # the skeleton's order
            # the largest escapes, to rounding (a chunk's sets are evaluated at its own frames'
            # offsets, which differ from another frame's in the last bits; a rigid motion's
            # joints tie, so which of them is listed may differ), each at its own frame pair
            assert [w.excess_m for w in c.worst] == pytest.approx(
                [w.excess_m for w in r.worst], abs=1e-12)  # fmt: skip
            for w in c.worst:
                assert t[w.frame] == w.t_s and np.isclose(t - w.t_s, w.dt_s, atol=1e-15).any()


def test_memory_does_not_grow_with_the_recording() -> None:
    """The analysis holds one chunk of frame pairs at a time: four times the frames take no more
    peak memory (traced numpy allocations) in chunks, where one piece takes far more."""
    import tracemalloc

    reach, t, y = _tight_uniform()
    rec = load_recording("02_01")
    peaks = {}
    for n in (200, 800):
        for pairs in (2000, 10**9):
            tracemalloc.start()
            containment(reach, rec.times_s[:n], rec.positions_m[:n], 0.3, pairs_per_chunk=pairs)
            peaks[n, pairs] = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
    assert peaks[800, 10**9] > 1.5 * peaks[200, 10**9]  # the measure sees the growth
    assert peaks[800, 2000] < 1.1 * peaks[200, 2000]
