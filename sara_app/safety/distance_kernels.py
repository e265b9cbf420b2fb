"""A cycle's reported separation in one compiled call (``Shield.min_distance``): the robot's link
capsules at one configuration (:func:`~sara_app.robot.occupancy_kernels.fk_kernel` and
``ends_kernel``) and their smallest surface distance to the measured body parts of the people
(:func:`~sara_app.geometry.shape_kernels.segment_closest`).

It was pinocchio's link capsules and :func:`~sara_app.safety.ssm.body_distance` per person:
about 40 us of a live worker's cycle for a number on the verdict (those two are this kernel's
oracle in ``tests/test_distance_kernels.py``). Numba's cache checks only this file: the source
digests of the files whose kernels it calls are a closure variable (``sara_app.kernel_types``).
"""

from __future__ import annotations

import math
from typing import Any

from numba import njit

from sara_app.geometry import shape_kernels
from sara_app.geometry.shape_kernels import segment_closest
from sara_app.kernel_types import F8, RO1, RO3, ROI1, ROI2, W2, W4, source_digest
from sara_app.robot import occupancy_kernels
from sara_app.robot.occupancy_kernels import ends_kernel, fk_kernel

__all__ = ["min_distance_kernel", "separation"]


@njit  # calls kernels of other files: compiled into its callers (kernel_types, caching)
def separation(
    E: Any, s: int, robot_radius_m: Any, Y: Any, part_joints: Any, half_thickness_m: Any
) -> float:
    """Smallest surface distance (m; negative: overlap; NaN when any pair's is) between the
    link capsules ``E[s] (L, 2, 3)`` of radii ``robot_radius_m (L,)`` and the body-part
    capsules of the people's joints ``Y (H, J, 3)``: ``part_joints (P, 2)``, radii
    ``half_thickness_m (P,)``; ``inf`` without people. :func:`min_distance_kernel` at one
    configuration; the SSM cycle's kernel at its command (the checked plan's sample 1, whose
    capsule ends its occupancy computed: :mod:`~sara_app.safety.ssm_cycle_kernels`)."""
    best = math.inf
    for h in range(Y.shape[0]):
        for p in range(part_joints.shape[0]):
            a, b = part_joints[p, 0], part_joints[p, 1]
            for i in range(E.shape[1]):
                d = segment_closest(
                    Y[h, a, 0], Y[h, a, 1], Y[h, a, 2], Y[h, b, 0], Y[h, b, 1], Y[h, b, 2],
                    E[s, i, 0, 0], E[s, i, 0, 1], E[s, i, 0, 2],
                    E[s, i, 1, 0], E[s, i, 1, 1], E[s, i, 1, 2],
                )[0]  # fmt: skip
                g = d - half_thickness_m[p] - robot_radius_m[i]
                if g != g:  # NaN: no distance can be claimed
                    return g
                best = min(best, g)
    return best


def _make_kernel() -> Any:
    """Build :func:`min_distance_kernel` with its callees' source digests in the closure."""
    sources = source_digest(occupancy_kernels) + source_digest(shape_kernels)

    @njit(F8(RO1, ROI1, RO3, ROI1, W4, ROI1, RO3, W4, W2, RO1, RO3, ROI2, RO1), cache=True)
    def min_distance_kernel(
        q: Any,
        q_index: Any,
        N: Any,
        parents: Any,
        H: Any,
        link_joint: Any,
        ends_joint: Any,
        E: Any,
        Q: Any,
        robot_radius_m: Any,
        Y: Any,
        part_joints: Any,
        half_thickness_m: Any,
    ) -> float:
        """Smallest surface distance (m; negative: overlap; NaN when any pair's is) between
        the link capsules ``(L,)`` of radii ``robot_radius_m`` at ``q (n,)`` and the body-part
        capsules of the people's joints ``Y (H, J, 3)``: ``part_joints (P, 2)``, radii
        ``half_thickness_m (P,)``; ``inf`` without people. The kinematics' constants are
        :meth:`RobotOccupancy.kernel_arrays <sara_app.robot.occupancy.RobotOccupancy>`;
        scratch: ``H (1, n+1, 4, 4)`` with the base pose in ``H[0, 0]`` and rows 3 of
        ``[0, 0, 0, 1]``, ``E (1, L, 2, 3)``, ``Q (1, n)``."""
        for j in range(q_index.shape[0]):
            Q[0, j] = q[q_index[j]]
        fk_kernel(Q, N, parents, H)
        ends_kernel(H, link_joint, ends_joint, E, 1)
        if len(sources) == 0:  # never: the digests tie the cache to the callees
            return math.nan
        return separation(E, 0, robot_radius_m, Y, part_joints, half_thickness_m)

    return min_distance_kernel


min_distance_kernel = _make_kernel()
