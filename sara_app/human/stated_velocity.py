"""A tracker's stated joint velocities, checked against the positions before they are used.

A skeleton may carry velocities with an uncertainty (``velocity_uncertainty_mps``, at least the
parameter set's ``delta_v``): the tracker claims ``v in B(v_s, dv_s)``. The cell's own estimate
from the positions (:mod:`sara_app.human.velocity`) claims ``v in B(v_e, dv_e)`` under the
assumptions every acceleration model already makes (``a_max`` per joint, positions within
``delta_y``). Both claims together put the true velocity in the lens ``B(v_s, dv_s) ∩ B(v_e,
dv_e)``. Where the scenario trusts the tracker's velocities (``inputs.trust_stated_velocities``)
the velocity handed to the acceleration models is the smallest of three balls that enclose that
lens: the stated one, the estimate's and the lens's own circle ball (below); by default it is
the estimate's, and the stated velocity is only checked against it.

- **Contradiction.** Where the two balls do not meet (``|v_s - v_e| > dv_s + dv_e``) at least
  one claim is false. The cell's estimate rests on the set's own assumptions (which the
  conformance monitor checks), so the stated velocity is the one not trusted: that joint uses
  the estimate, and the person is a fault (``stated_velocity``, for the monitor's ``recover_s``)
  so the operator sees a tracker whose velocities disagree with its positions (a frame
  transformation applied to positions only, a sign, a unit) and the robot stays on its verified
  failsafe meanwhile.
- **What trusting means.** Where the balls meet, a trusted stated velocity is used within its
  stated uncertainty: a wrong one that the positions cannot yet contradict narrows the set
  wrongly (measured: reversed velocities of slow joints made the effective set miss future
  positions the estimate's sets contain; hence off by default).
  How wrong it can be without a fault: less than ``dv_s + dv_e`` from the estimate; ``dv_e`` is
  ``2 sqrt(delta_y a_max)`` at its best lag (``delta_y`` 4 mm, a wrist's ``a_max`` 100 m/s^2:
  1.3 m/s), so reversed velocities are caught once the joint moves faster than about half of
  that. Measured on recordings: docs/measurements/2026-11-30-stated-velocities.md.
- **No estimate** (a first frame, a joint the gate distrusts): nothing to check against; the
  stated ball is used as stated (a held joint's stated velocity is never used: its bound is
  infinite before this check).

The lens's ball: with ``d = |v_e - v_s|`` and ``u`` their direction, the circle where the two
spheres meet lies at ``a = (d^2 + dv_s^2 - dv_e^2) / (2 d)`` from ``v_s`` along ``u``, radius
``h = sqrt(dv_s^2 - a^2)``. When ``0 <= a <= d`` each ball's part of the lens is a cap of at most
a hemisphere, so every point of it lies within ``h`` of the circle's centre (for a point of the
first sphere at height ``s >= a`` along ``u``: ``|x - c|^2 = dv_s^2 - 2as + a^2 <= h^2``);
otherwise the lens is bounded by the smaller ball alone. Checked against sampled lenses in
``tests/test_stated_velocity.py``; the compiled step
(:mod:`~sara_app.human.stated_velocity_kernels`: 1.8 us for 15 joints in a warm loop, 48 us
as numpy, 2026-11-30)
is compared there with the plain numpy version in ``tests/stated_velocity_reference.py``.
"""

from __future__ import annotations

import numpy as np

from sara_app.errors import InputError
from sara_app.human.stated_velocity_kernels import reconcile_step
from sara_app.kernel_types import as_f8, entry

_STEP = entry(reconcile_step)


def reconcile(
    v_s: np.ndarray, dv_s: np.ndarray, v_e: np.ndarray, dv_e: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The velocity ``(J, 3)`` m/s and its bound ``(J,)`` to use, from the stated ``v_s (J, 3)``,
    ``dv_s (J,)`` and the estimate ``v_e (J, 3)``, ``dv_e (J,)`` (``inf``: none); plus per joint
    whether the two contradict ``(J,)`` and their gap ``|v_s - v_e|`` ``(J,)`` (m/s; NaN where
    a bound is infinite). New arrays (the caller keeps them)."""
    v_s, dv_s, v_e, dv_e = as_f8(v_s), as_f8(dv_s), as_f8(v_e), as_f8(dv_e)
    J = dv_s.shape[0]
    if v_s.shape != (J, 3) or v_e.shape != (J, 3) or dv_e.shape != (J,) or dv_s.ndim != 1:
        raise InputError(
            f"stated velocity {v_s.shape}, {dv_s.shape}; estimate {v_e.shape}, {dv_e.shape}: "
            f"expected ({J}, 3), ({J},) twice"
        )
    v, dv = np.empty((J, 3)), np.empty(J)
    contradicted, gap = np.empty(J, np.bool_), np.empty(J)
    _STEP(v_s, dv_s, v_e, dv_e, v, dv, contradicted, gap)
    return v, dv, contradicted, gap
