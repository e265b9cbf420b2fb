"""The compiled SSM check (sara_app.safety.ssm_kernels, run by SsmVerifier.verify) against the
Python composition of the same kernels (tests/ssm_reference.py): the same verdict, free and
evaluated intervals and closest distances, bit for bit, for 1-8 people with their own ages,
every model order (the arm model included), widened people, height-bounded legs and non-finite
inputs."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from ssm_reference import verify_reference
from test_ssm import REACH, SETTINGS, cell

from sara_app.geometry import shape_kernels
from sara_app.human import reach_kernels
from sara_app.human.reach import MODELS
from sara_app.kernel_types import source_digest
from sara_app.safety.ssm import SsmResult, SsmVerifier
from sara_app.safety.ssm_kernels import model_verdicts, ssm_kernel


def _assert_same(a: SsmResult, b: SsmResult) -> None:
    assert a.safe == b.safe
    np.testing.assert_array_equal(a.free, b.free)
    np.testing.assert_array_equal(a.evaluated, b.evaluated)
    np.testing.assert_array_equal(a.closest_m, b.closest_m)
    np.testing.assert_array_equal(a.parts_clear, b.parts_clear)


def _caps(rng: np.random.Generator, H: int, P: int) -> np.ndarray:
    """``(H, P, 2)`` height bounds of random parts of random people (no bound elsewhere)."""
    caps = np.stack([rng.uniform(-0.5, 1.5, (H, P)), rng.uniform(0.0, 2.0, (H, P))], axis=2)
    caps[..., 0][rng.random((H, P)) < 0.4] = np.inf
    return caps


@SETTINGS
@given(cell(), st.integers(0, 2**31 - 1))
def test_equals_the_python_composition(c: dict, seed: int) -> None:
    rng = np.random.default_rng(seed)
    vf = SsmVerifier(REACH, c["models"])
    H, P = len(c["y"]), REACH.skeleton.n_parts
    widen = None
    if rng.random() < 0.5:  # some people measured less precisely than the parameters assume
        widen = rng.uniform(0.0, 0.05, (H, len(MODELS), P)) * (rng.random((H, 1, 1)) < 0.6)
    caps = _caps(rng, H, P) if rng.random() < 0.5 else None
    args = (c["y"], c["v"], c["dv"], c["age"], c["times"], c["ends"], c["radius"], widen, caps)
    _assert_same(vf.verify(*args), verify_reference(vf, *args))


def test_a_height_bound_clears_a_part_of_the_links_above_it_only() -> None:
    """A leg part's set reaches the robot: with a bound below every link it is clear; with the
    bound between two links, clear exactly when the links under it are out of the set's reach
    (the reference agrees); the bound grows with time (rate) and age."""
    vf = SsmVerifier(REACH, ("vel",))
    sk = REACH.skeleton
    P, J = sk.n_parts, sk.n_joints
    y = np.zeros((1, J, 3)) + [0.0, 0.0, 1.0]
    v, dv = np.zeros((1, J, 3)), np.zeros((1, J))
    times = np.array([0.0, 0.1])
    # two horizontal links through the person: one at 1.3 m, one at 0.9 m
    ends = np.array([[[[-0.5, 0, 1.3], [0.5, 0, 1.3]], [[-0.5, 0, 0.9], [0.5, 0, 0.9]]]])
    radius = np.full((1, 2), 0.05)
    legs = [sk.parts.index(p) for p in sk.parts if p.endswith(("thigh", "shin", "foot"))]

    def parts(caps: np.ndarray | None, age_s: float = 0.0) -> np.ndarray:
        a = (y, v, dv, np.array([age_s]), times, ends, radius, None, caps)
        res = vf.verify(*a)
        _assert_same(res, verify_reference(vf, *a))
        return res.parts_clear[0, 0]

    assert not parts(None)[legs].any()  # every leg set touches the robot
    caps = np.stack([np.full(P, np.inf), np.zeros(P)], axis=1)
    caps[legs, 0] = 0.5  # below both links
    assert parts(caps[None])[legs].all()
    caps[legs, 0] = 1.1  # between them: the 0.9 m link still touches
    assert not parts(caps[None])[legs].any()
    ends[0, 1, :, 2] = 1.3  # both links at 1.3 m
    assert parts(caps[None])[legs].all()
    caps[legs, 1] = 1.0  # rising 1 m/s: 1.2 at the interval's end, still below 1.3 - 0.05
    assert parts(caps[None])[legs].all()
    assert not parts(caps[None], age_s=0.2)[legs].any()  # 0.2 s older: 1.4 m
    upper = [p for p in range(P) if p not in legs]
    assert not parts(caps[None])[upper].any()  # parts without a bound are not cleared by it


def test_several_people_and_non_finite_inputs_equal_the_reference() -> None:
    """Up to 8 people around a moving robot, one of them with a NaN joint velocity and one with
    an infinite velocity bound: the same result as the reference (NaN sets touch everything)."""
    rng = np.random.default_rng(3)
    vf = SsmVerifier(REACH, ("acc", "vel", "pos"))
    for H in (1, 2, 4, 8):
        for _ in range(10):
            y = np.stack([rng.normal(0, 0.3, (15, 3)) + [rng.uniform(-2, 2), rng.uniform(-2, 2), 1]
                          for _ in range(H)])  # fmt: skip
            v = rng.normal(0, 1.0, y.shape)
            dv = rng.uniform(0, 0.3, (H, 15))
            if H > 1:
                v[1, 4] = np.nan
                dv[0, 2] = np.inf
            age = rng.uniform(0, 0.05, H)
            K = int(rng.integers(1, 12))
            times = np.concatenate([[0.0], np.cumsum(rng.uniform(0.002, 0.03, K))])
            p0 = rng.uniform(-0.6, 0.6, (K, 7, 3)) + [0, 0, 0.5]
            ends = np.stack([p0, p0 + rng.normal(0, 0.1, p0.shape)], axis=2)
            radius = rng.uniform(0.03, 0.1, (K, 7))
            args = (y, v, dv, age, times, ends, radius)
            _assert_same(vf.verify(*args), verify_reference(vf, *args))


def test_cache_key_carries_the_callees_sources() -> None:
    cells = [c.cell_contents for c in ssm_kernel.py_func.__closure__ or ()]
    text = "".join(c for c in cells if isinstance(c, str))
    for module in (shape_kernels, reach_kernels):
        assert source_digest(module) in text, module.__name__


@SETTINGS
@given(cell(), st.integers(0, 2**31 - 1))
def test_the_order_changes_the_work_not_the_verdict_or_the_parts_cleared(
    c: dict, seed: int
) -> None:
    """Every model tried first in turn (:meth:`SsmVerifier.promote`): the same verdict and the
    same body parts proved clear; each order's result equals the reference's in that order, and
    names its models in it."""
    rng = np.random.default_rng(seed)
    vf = SsmVerifier(REACH, c["models"])
    H, P = len(c["y"]), REACH.skeleton.n_parts
    caps = _caps(rng, H, P) if rng.random() < 0.5 else None
    args = (c["y"], c["v"], c["dv"], c["age"], c["times"], c["ends"], c["radius"], None, caps)
    first = vf.verify(*args)
    for m in c["models"]:
        vf.promote(m)
        assert vf.order[0] == m and sorted(vf.order) == sorted(c["models"])
        res = vf.verify(*args)
        assert res.models == vf.order
        _assert_same(res, verify_reference(vf, *args))
        assert res.safe == first.safe
        np.testing.assert_array_equal(res.parts_clear, first.parts_clear)


def test_model_verdicts_are_the_reductions_over_people_and_intervals() -> None:
    """``model_verdicts`` (the cycle result's per-model flags) against numpy's reductions, on
    random checks of 1-5 people, 1-6 models and 1-12 intervals, sparse and dense."""
    rng = np.random.default_rng(7)
    for _ in range(300):
        H, M, K = (int(x) for x in rng.integers(1, (6, 7, 13)))
        p = rng.choice([0.02, 0.5, 0.98])
        evaluated, free = rng.random((2, H, M, K)) < p
        out = np.empty((2, M), np.bool_)
        model_verdicts(evaluated, free, out)
        np.testing.assert_array_equal(out[0], evaluated.all(axis=(0, 2)))
        np.testing.assert_array_equal(out[1], free.all(axis=(0, 2)))
