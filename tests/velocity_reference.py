"""The streaming velocity estimate's per-frame step in plain numpy: the oracle of
``sara_app.human.velocity_kernels.velocity_step`` (the library's ``VelocityEstimator.update``
before it was compiled)."""

from __future__ import annotations

import numpy as np

from sara_app.human.velocity import VelocityEstimator, velocity_error_bound


class ReferenceVelocityEstimator(VelocityEstimator):
    """A :class:`VelocityEstimator` whose ``update`` is the numpy version."""

    def update(
        self, t_s: float, y: np.ndarray, trusted: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        self.check_stamp(t_s)
        self.times[1:] = self.times[:-1]
        self.frames[1:] = self.frames[:-1]
        self.times[0] = t_s
        self.frames[0] = y
        self.trusted[1:] = self.trusted[:-1]
        self.trusted[0] = True if trusted is None else trusted
        self.count = min(self.count + 1, len(self.times))
        n = self.count - 1
        if n == 0:
            self.v[:] = 0.0
            self.dv[:] = np.inf
            return self.v, self.dv
        dts = t_s - self.times[1 : n + 1]
        bounds = velocity_error_bound(dts[:, None], self.delta_y_m, self.a_max[None, :])
        best = np.argmin(bounds, axis=0)
        joints = np.arange(self.a_max.shape[0])
        bound = bounds[best, joints]
        past = self.frames[1 + best, joints]
        self.v[:] = (y - past) / dts[best][:, None]
        self.dv[:] = np.where(self.trusted[0] & self.trusted[1 + best, joints], bound, np.inf)
        self.v[~np.isfinite(self.dv)] = 0.0
        return self.v, self.dv
