"""Joint velocities from positions, with an explicit bound on the estimate's error.

A backward difference over a lag h, v_hat(t) = (y(t) - y(t - h)) / h, with positions known to
within delta_y (Euclidean) and a joint acceleration bounded by a_max, is off by at most

    |v_hat(t) - v(t)| <= 2 delta_y / h + a_max h / 2

(noise at both ends, plus the Taylor remainder of a motion whose acceleration is bounded). The
bound is smallest at h* = 2 sqrt(delta_y / a_max); each joint uses the lag in reach closest to
its optimum. The bound assumes a_max holds: it is exactly the assumption of the ACC model that
consumes it, so the model stays sound under its own assumptions.

Frames the tracking quality gate distrusts for a joint (:mod:`sara_app.human.gate`) are never
used for that joint: a glitch at either end would break the bound. When the frame at the best
lag (or the current one) is distrusted, the joint has no estimate for this frame (infinite
bound), never one from another lag: the estimate then depends only on the frames' stamps and
those two frames, so a history that differs only in what the gate distrusted gives the same
estimate or none, never a differently centred one (a fallback lag once let a person whose gate
had learned another body's bones be cleared where a fresh person at the same place was not:
``tests/test_ingest_history.py``).
"""

from __future__ import annotations

import numpy as np

from sara_app.errors import InputError
from sara_app.human.velocity_kernels import velocity_step
from sara_app.kernel_types import as_f8


def velocity_error_bound(lag_s: np.ndarray, delta_y_m: float, a_max_mps2: np.ndarray) -> np.ndarray:
    """Error bound of a backward difference with lag ``lag_s`` (broadcast with a_max), m/s."""
    return 2.0 * delta_y_m / lag_s + 0.5 * a_max_mps2 * lag_s


def _best_lags(
    dts: np.ndarray, delta_y_m: float, a_max: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """For candidate lags ``(L,)`` and joints ``(J,)``: index of the best lag and its bound."""
    bounds = velocity_error_bound(dts[:, None], delta_y_m, a_max[None, :])  # (L, J)
    best = np.argmin(bounds, axis=0)
    return best, bounds[best, np.arange(a_max.shape[0])]


def estimate_recording(
    times_s: np.ndarray,
    positions_m: np.ndarray,
    delta_y_m: float,
    a_max_mps2: np.ndarray,
    max_lag_frames: int = 8,
    trusted: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Causal velocity estimates for a whole recording.

    ``positions_m`` ``(T, J, 3)``; ``trusted`` ``(T, J)`` the gate's verdicts (None: all);
    returns ``v (T, J, 3)`` and the error bound ``dv (T, J)``. Frame 0 has no past: its bound
    is infinite (the ACC model is then unusable there), as for an untrusted joint.
    """
    T, J, _ = positions_m.shape
    ok = np.ones((T, J), bool) if trusted is None else np.asarray(trusted, bool)
    v = np.zeros_like(positions_m)
    dv = np.full((T, J), np.inf)
    for i in range(1, T):
        lags = np.arange(1, min(max_lag_frames, i) + 1)
        dts = times_s[i] - times_s[i - lags]
        best, bound = _best_lags(dts, delta_y_m, a_max_mps2)
        past = positions_m[i - lags[best], np.arange(J)]
        v[i] = (positions_m[i] - past) / dts[best][:, None]
        dv[i] = np.where(ok[i] & ok[i - lags[best], np.arange(J)], bound, np.inf)
    v[~np.isfinite(dv)] = 0.0
    return v, dv


class VelocityEstimator:
    """Streaming version: keeps the last ``max_lag_frames`` frames of one human."""

    def __init__(
        self, n_joints: int, delta_y_m: float, a_max_mps2: np.ndarray, max_lag_frames: int = 8
    ) -> None:
        self.delta_y_m = delta_y_m
        self.a_max = np.asarray(a_max_mps2, dtype=float)
        self.times = np.full(max_lag_frames + 1, -np.inf)
        self.frames = np.zeros((max_lag_frames + 1, n_joints, 3))
        self.trusted = np.ones((max_lag_frames + 1, n_joints), bool)
        self.count = 0
        self.v = np.zeros((n_joints, 3))
        self.dv = np.full(n_joints, np.inf)
        self._all_trusted = np.ones(n_joints, bool)

    def reset(self) -> None:
        self.count = 0
        self.dv[:] = np.inf

    def retune(self, delta_y_m: float, a_max_mps2: np.ndarray) -> None:
        """New error parameters (a scenario edit); the frames kept serve the next update."""
        self.delta_y_m = delta_y_m
        self.a_max = np.asarray(a_max_mps2, dtype=float)
        self.dv[:] = np.inf

    def check_stamp(self, t_s: float) -> None:
        """Raise InputError when ``t_s`` does not advance past the newest frame's stamp."""
        if self.count and not t_s > self.times[0]:
            raise InputError(
                f"skeleton time stamp {t_s} does not advance past the previous {self.times[0]}"
            )

    def update(
        self, t_s: float, y: np.ndarray, trusted: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Add a frame; returns the velocity ``(J, 3)`` and its error bound ``(J,)`` at ``t_s``.
        ``trusted`` ``(J,)``: the gate's verdict per joint (None: all trusted).

        A time stamp that does not advance raises InputError (the caller drops the frame).
        """
        self.check_stamp(t_s)
        y = as_f8(y)
        ok = self._all_trusted if trusted is None else np.asarray(trusted, bool)
        per_joint = self.dv.shape
        if (
            y.shape != self.frames.shape[1:]
            or per_joint != ok.shape
            or per_joint != self.a_max.shape
        ):
            raise InputError(
                f"velocity: frame of shape {y.shape}, trusted {ok.shape}, a_max "
                f"{self.a_max.shape}; expected {self.frames.shape[1:]}, {self.dv.shape} twice"
            )
        self.count = velocity_step(
            self.times, self.frames, self.trusted, self.count, float(t_s), y, ok,
            float(self.delta_y_m), self.a_max, self.v, self.dv,
        )  # fmt: skip
        return self.v, self.dv
