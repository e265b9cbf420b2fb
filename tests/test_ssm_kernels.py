"""The compiled SSM check (sara_app.safety.ssm_kernels, run by SsmVerifier.verify) against the
Python composition of the same kernels (tests/ssm_reference.py): the same verdict, free and
evaluated intervals and closest distances, bit for bit, for 1-8 people with their own ages,
every model order (the arm model included), widened people and non-finite inputs."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from ssm_reference import verify_reference
from test_ssm import REACH, SETTINGS, cell

from sara_app.geometry import shape_kernels
from sara_app.human import reach_kernels
from sara_app.human.reach import MODELS
from sara_app.safety.contact_kernels import source_digest
from sara_app.safety.ssm import SsmResult, SsmVerifier
from sara_app.safety.ssm_kernels import ssm_kernel


def _assert_same(a: SsmResult, b: SsmResult) -> None:
    assert a.safe == b.safe
    np.testing.assert_array_equal(a.free, b.free)
    np.testing.assert_array_equal(a.evaluated, b.evaluated)
    np.testing.assert_array_equal(a.closest_m, b.closest_m)


@SETTINGS
@given(cell(), st.integers(0, 2**31 - 1))
def test_equals_the_python_composition(c: dict, seed: int) -> None:
    rng = np.random.default_rng(seed)
    vf = SsmVerifier(REACH, c["models"])
    H, P = len(c["y"]), REACH.skeleton.n_parts
    widen = None
    if rng.random() < 0.5:  # some people measured less precisely than the parameters assume
        widen = rng.uniform(0.0, 0.05, (H, len(MODELS), P)) * (rng.random((H, 1, 1)) < 0.6)
    args = (c["y"], c["v"], c["dv"], c["age"], c["times"], c["ends"], c["radius"], widen)
    _assert_same(vf.verify(*args), verify_reference(vf, *args))


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
