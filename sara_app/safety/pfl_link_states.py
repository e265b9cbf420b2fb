"""The link states a PFL check needs from one shielded trajectory, in one compiled call.

For the ``K+1`` samples of a trajectory along a path (``q``, the tangent ``dq/ds``, the path
speed ``s'``, its exact peak per interval ``sd_max``, joint bounds per interval): the joint
frames and capsule ends, the inertia matrices, each link's energy and twist at the samples
(:class:`~sara_app.robot.energy.LinkMotion`), the interval energy bound
(:func:`~sara_app.robot.energy.path_interval_energy_J`) and the Thm VI.2 velocity error
(:meth:`~sara_app.safety.velocity_error.VelocityErrorBound.eps_from_bounds` with the joint
jerk limits). The same compiled kernels as those functions, called from one kernel with
buffers kept per trajectory length; the composition of the Python methods is its reference in
``tests/test_pfl_link_states.py`` (tested equal).

Bad samples as in :class:`LinkMotion`: a sample whose ``q``, ``dq/ds`` or ``s'`` is not
finite gets infinite energy, NaN twists and NaN capsule ends; a NaN in ``s'`` or ``sd_max``
makes the interval's energy bound infinite. Nothing raises on values; wrong shapes raise
:class:`InputError`.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

from sara_app.errors import InputError
from sara_app.kernel_types import RO1 as _RO1
from sara_app.kernel_types import RO2 as _RO2
from sara_app.kernel_types import RO3 as _RO3
from sara_app.kernel_types import ROC2 as _ROC2
from sara_app.kernel_types import ROCI2 as _ROCI2
from sara_app.kernel_types import ROI1 as _ROI1
from sara_app.kernel_types import W1 as _W1
from sara_app.kernel_types import W2 as _W2
from sara_app.kernel_types import W3 as _W3
from sara_app.kernel_types import W4 as _W4
from sara_app.kernel_types import WB1 as _WB1
from sara_app.kernel_types import WC2 as _WC2
from sara_app.kernel_types import WC3 as _WC3
from sara_app.kernel_types import source_digest
from sara_app.robot import crba_kernels as crba_module
from sara_app.robot import energy as energy_module
from sara_app.robot import occupancy_kernels
from sara_app.robot.crba_kernels import crba_kernel
from sara_app.robot.energy import LinkMotion, LinkSamples, energy_twist_kernel, path_energy_kernel
from sara_app.robot.occupancy_kernels import ends_kernel, fk_kernel
from sara_app.safety import contact_kernels
from sara_app.safety.contact_kernels import jerk_coefficients
from sara_app.safety.velocity_error import VelocityErrorBound

__all__ = ["PathLinkStates"]


def _make_kernel() -> Any:
    """Build :func:`path_states_kernel`. It calls kernels of four other files and numba's cache
    checks only its own: their source digests are a closure variable, which numba hashes into
    the cache key (as :func:`sara_app.safety.contact_kernels._make_classify_kernel` does)."""
    sources = "".join(
        source_digest(m) for m in (occupancy_kernels, crba_module, energy_module, contact_kernels)
    )

    @njit(
        types.void(
            _RO2, _RO2, _RO1, _RO1, _RO1, _RO2, _RO2, _RO2,  # trajectory, bounds, jerk limits
            _ROI1, _RO3, _ROI1, _ROI1, _RO3,  # kinematics
            _ROCI2, _ROC2, _WC2,  # CRBA constants, scratch
            _RO2, _RO2, _ROI1, _ROI1, _ROI1, _RO2,  # mask, axes, v_index; jerk order, parent, D
            _W2, _W2, _W2, _W1, _WB1, _W4, _WC3, _W4, _W2, _W2, _W3, _W3, _W2, _W2, _W1,
        ),
        cache=True,
    )  # fmt: skip
    def path_states_kernel(
        q: np.ndarray,
        dq_ds: np.ndarray,
        sd: np.ndarray,
        sd_max: np.ndarray,
        times: np.ndarray,
        v_bound: np.ndarray,
        a_bound: np.ndarray,
        j_max: np.ndarray,
        q_index: np.ndarray,
        N: np.ndarray,
        parents: np.ndarray,
        link_joint: np.ndarray,
        ends_joint: np.ndarray,
        crba_ints: np.ndarray,
        crba_consts: np.ndarray,
        crba_work: np.ndarray,
        mask: np.ndarray,
        axes: np.ndarray,
        v_index: np.ndarray,
        order: np.ndarray,
        parent: np.ndarray,
        D: np.ndarray,
        Q: np.ndarray,
        Qj: np.ndarray,
        V: np.ndarray,
        scale: np.ndarray,
        bad: np.ndarray,
        H: np.ndarray,
        M: np.ndarray,
        ends: np.ndarray,
        G: np.ndarray,
        T: np.ndarray,
        pd: np.ndarray,
        w: np.ndarray,
        E_int: np.ndarray,
        eps: np.ndarray,
        dt_scale: np.ndarray,
    ) -> None:
        """Inputs ``q, dq_ds (S, n)``, ``sd, times (S,)``, ``sd_max (K,)``, ``v_bound, a_bound
        (K, n)``, ``j_max (1, n)`` and the model constants of :class:`PathLinkStates`; writes
        the clean inputs ``Q, V (S, n)`` (bad rows zeroed), ``Qj`` (joint order), ``scale``,
        ``bad (S,)``, the frames ``H``, inertia ``M``, ``ends``, ``G, T (S, L)``, ``pd, w (S,
        L, 3)`` and ``E_int, eps (K, L)``, ``dt_scale (K,)``."""
        if len(sources) == 0:  # never: ties the cache to the callees' files
            return
        S, n = q.shape
        for s in range(S):
            b = not math.isfinite(sd[s])
            for a in range(n):
                if not (math.isfinite(q[s, a]) and math.isfinite(dq_ds[s, a])):
                    b = True
            bad[s] = b
            scale[s] = 0.0 if b else sd[s]
            for a in range(n):
                Q[s, a] = 0.0 if b else q[s, a]
                V[s, a] = 0.0 if b else dq_ds[s, a]
            for a in range(n):
                Qj[s, a] = Q[s, q_index[a]]
        fk_kernel(Qj, N, parents, H)
        ends_kernel(H, link_joint, ends_joint, ends, S)
        for s in range(S):
            if bad[s]:
                ends[s] = math.nan
        crba_kernel(Q, crba_ints, crba_consts, crba_work, M)
        energy_twist_kernel(V, scale, M, mask, H, axes, v_index, ends, bad, G, T, pd, w)
        path_energy_kernel(G, T, sd, sd_max, E_int)
        for k in range(S - 1):
            dt = times[k + 1] - times[k]
            dt_scale[k] = dt * dt / 8.0
        jerk_coefficients(v_bound, a_bound, j_max, order, parent, D, dt_scale, eps)

    return path_states_kernel


path_states_kernel = _make_kernel()


class PathLinkStates:
    """Link states of shielded trajectories for one robot (buffers per trajectory length;
    outputs are views, valid until the next call with the same number of samples).

    ``motion``: the :class:`LinkMotion` whose kinematics, CRBA and supports are used;
    ``velocity_error``: the Thm VI.2 bound of the same robot.
    """

    def __init__(self, motion: LinkMotion, velocity_error: VelocityErrorBound) -> None:
        self.motion, self.velocity_error = motion, velocity_error
        model = motion.model
        self.n_dof, self.n_links = model.n_dof, model.n_links
        self._j_max = np.asarray(model.limits.j_max, dtype=np.float64).reshape(1, -1).copy()
        crba = motion.compiled_crba
        q_index, N, parents, link_joint, ends_joint, axes, T0 = motion.occupancy.kernel_arrays()
        mask, v_index = motion.support_arrays()
        # model constants, in the kernel's order
        self._kinematics = (q_index, N, parents, link_joint, ends_joint)
        self._crba = crba.kernel_arrays()
        self._links = (mask, axes, v_index, *velocity_error.kernel_arrays())
        self._T0 = np.asarray(T0, dtype=np.float64)
        self._buffers: dict[int, tuple[np.ndarray, ...]] = {}

    def buffers_for(self, S: int) -> tuple[np.ndarray, ...]:
        """The kernel's buffers for ``S`` samples (allocated once per ``S``)."""
        b = self._buffers.get(S)
        if b is None:
            n, L, K = self.n_dof, self.n_links, S - 1
            H = np.zeros((S, n + 1, 4, 4))
            H[:, :, 3, 3] = 1.0
            H[:, 0] = self._T0
            b = self._buffers[S] = (
                np.empty((S, n)), np.empty((S, n)), np.empty((S, n)), np.empty(S),
                np.empty(S, dtype=bool), H, np.empty((S, n, n)), np.empty((S, L, 2, 3)),
                np.empty((S, L)), np.empty((S, L)), np.empty((S, L, 3)), np.empty((S, L, 3)),
                np.empty((K, L)), np.empty((K, L)), np.empty(K),
            )  # fmt: skip
        return b

    def kernel_constants(self) -> tuple[np.ndarray, ...]:
        """The robot's constants in the kernel's order, after the trajectory's arrays."""
        return (self._j_max, *self._kinematics, *self._crba, *self._links)

    def base_pose(self) -> np.ndarray:
        """``T_world_base (4, 4)``: row 0 of every sample's joint frames in the buffers."""
        return self._T0

    def inputs(self, traj: Any) -> tuple[np.ndarray, ...]:
        """The trajectory's arrays as float64, shapes checked."""
        arrays = [
            np.asarray(getattr(traj, name), dtype=np.float64)
            for name in ("q", "dq", "sd", "sd_max", "times", "v_bound", "a_bound")
        ]
        q, dq, sd, sd_max, times, v_bound, a_bound = arrays
        S, n = (q.shape[0], self.n_dof) if q.ndim == 2 else (-1, self.n_dof)
        want = ((S, n), (S, n), (S,), (S - 1,), (S,), (S - 1, n), (S - 1, n))
        if S < 2 or any(a.shape != w for a, w in zip(arrays, want)):
            raise InputError(
                "trajectory arrays q, dq, sd, sd_max, times, v_bound, a_bound have shapes "
                f"{[a.shape for a in arrays]}; expected (S, {n}), (S, {n}), (S,), (S-1,), (S,), "
                f"(S-1, {n}), (S-1, {n}) with S >= 2 samples"
            )
        return q, dq, sd, sd_max, times, v_bound, a_bound

    def evaluate(self, traj: Any) -> tuple[LinkSamples, np.ndarray, np.ndarray]:
        """``(samples, E_int (K, L) J, eps_v (K, L) m/s)`` of a trajectory with arrays ``q,
        dq (K+1, n)``, ``sd, times (K+1,)``, ``sd_max (K,)``, ``v_bound, a_bound (K, n)`` (a
        :class:`~sara_app.robot.shielded.ShieldedTrajectory`)."""
        q, dq, sd, sd_max, times, v_bound, a_bound = self.inputs(traj)
        b = self.buffers_for(q.shape[0])
        path_states_kernel(
            q, dq, sd, sd_max, times, v_bound, a_bound, self._j_max, *self._kinematics,
            *self._crba, *self._links, *b,
        )  # fmt: skip
        T, ends, pd, w, G = b[9], b[7], b[10], b[11], b[8]
        return LinkSamples(T, ends, pd, w, G), b[12], b[13]
