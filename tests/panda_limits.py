"""Panda-like joint limits and a dense-sampling limit check shared by the motion tests."""

from __future__ import annotations

import numpy as np

from sara_app.robot.model import JointLimits

PANDA = JointLimits(
    q_min=np.array([-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]),
    q_max=np.array([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973]),
    v_max=np.array([2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61]),
    a_max=np.array([15, 7.5, 10, 12.5, 15, 20, 20.0]),
    j_max=np.array([7500, 3750, 5000, 6250, 7500, 10000, 10000.0]),
)
HOME = np.array([0.0, 0.0, 0.0, -1.5, 0.0, 1.5, 0.0])
H = 1e-4  # dense sampling step (s)
DT = 1e-3  # control step (s)


def check_limits(q: np.ndarray, h: float = H, limits: JointLimits = PANDA) -> None:
    """Finite-difference velocity, acceleration and jerk of ``q`` ``(K, n)`` within limits."""
    err_q = 16 * np.finfo(float).eps * max(1.0, float(np.max(np.abs(q))))
    assert np.all(q >= limits.q_min - 1e-12) and np.all(q <= limits.q_max + 1e-12)
    for k, lim in ((1, limits.v_max), (2, limits.a_max), (3, limits.j_max)):
        d = np.diff(q, k, axis=0) / h**k
        tol = 2**k * err_q / h**k + 1e-9 * lim
        excess = np.abs(d) - (lim + tol)
        assert np.all(excess <= 0), (
            k,
            float(np.max(excess)),
            np.unravel_index(excess.argmax(), excess.shape),
        )
