"""The velocity estimate's compiled step (``sara_app.human.velocity_kernels``) against its numpy
oracle (``tests/velocity_reference.py``): random streams (jittered and irregular stamps, joints
distrusted at random, retuned bounds, resets) give the same estimates, bounds and rings at
every frame."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from velocity_reference import ReferenceVelocityEstimator

from sara_app.errors import InputError
from sara_app.human.velocity import VelocityEstimator


@given(st.integers(0, 2**31 - 1), st.sampled_from([15, 9]), st.integers(1, 10))
@settings(max_examples=60, deadline=None)
def test_the_compiled_step_equals_the_numpy_reference(seed: int, J: int, lags: int) -> None:
    rng = np.random.default_rng(seed)
    a_max = rng.uniform(5.0, 300.0, J)
    dy = float(rng.choice([0.004, 0.012]))
    est = (VelocityEstimator(J, dy, a_max.copy(), lags),
           ReferenceVelocityEstimator(J, dy, a_max.copy(), lags))  # fmt: skip
    t, y = 10.0, rng.normal(size=(J, 3))
    for frame in range(60):
        t += float(rng.choice([0.001, 0.01, 0.0333, 0.1]))
        y = y + rng.normal(scale=0.01, size=(J, 3))
        trusted = None if rng.random() < 0.5 else rng.random(J) > 0.2
        if rng.random() < 0.03:
            for e in est:
                e.reset()
        if rng.random() < 0.03:
            new_a = rng.uniform(5.0, 300.0, J)
            for e in est:
                e.retune(0.01, new_a.copy())
        out = [e.update(t, y.copy(), None if trusted is None else trusted.copy()) for e in est]
        np.testing.assert_array_equal(out[0][1], out[1][1], err_msg=f"dv, frame {frame}")
        np.testing.assert_allclose(out[0][0], out[1][0], rtol=1e-13, atol=0,
                                   err_msg=f"v, frame {frame}")  # fmt: skip
        for name in ("times", "frames", "trusted"):
            np.testing.assert_array_equal(getattr(est[0], name), getattr(est[1], name))
        assert est[0].count == est[1].count


def test_a_frame_of_the_wrong_shape_is_an_input_error() -> None:
    """The kernel reads rows by index: a frame that does not fit never reaches it."""
    est = VelocityEstimator(15, 0.01, np.full(15, 50.0))
    with pytest.raises(InputError, match=r"\(9, 3\)"):
        est.update(0.0, np.zeros((9, 3)))
    with pytest.raises(InputError, match="trusted"):
        est.update(0.0, np.zeros((15, 3)), np.ones(9, bool))
