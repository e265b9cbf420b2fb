"""Reconstruction failures in motion-capture recordings, told apart from motion, for fitting.

A BVH file's bones are rigid, so the tracking gate's bone check cannot see a failed
reconstruction: a joint angle that flips swings a whole limb through a metre and back in a few
frames (TUM PickPlaceCloseHuman takes: wrists at 14-108 m/s), or one frame jumps and returns
(CMU 62_11: the head at 11 m/s and 2 500 m/s^2 for one frame). Fitted as motion they would make
the sets so wide that no robot near a person moves. They are left out of the fit by two
ceilings of what a person can do, both stated in the set they produce:

- ``max_speed_mps``: no joint of a person at work moves faster. A deliberate boxing punch, the
  fastest motion of the given recordings (CMU 13_18), peaks at 6-7 m/s at the wrist;
- ``max_acc_mps2``: no joint accelerates harder over one frame, beyond what the tracker's noise
  bound ``delta_y`` can fake: a one-frame second difference of noise alone stays below
  ``4 delta_y / dt^2`` (each of the three positions off by at most ``delta_y``).

A frame that breaks a ceiling starts a failure; the failure extends over the neighbouring frames
while that joint still moves faster than half the speed ceiling (hysteresis: the swing out and
back is one failure, not two spikes), plus ``margin_s`` on each side. The recording is then split
into the pieces between failures; fitting and its containment figures use the pieces, and the
frames left out are listed. A live cell does not rely on this: there its conformance monitor
faults on motion beyond the set in force, and the robot stays on its verified failsafe.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sara_app.errors import ParameterError
from sara_app.human.recording import Recording


@dataclass(frozen=True)
class Ceilings:
    """What a person can do at most (see the module notes); in m/s, m/s^2 and s."""

    max_speed_mps: float
    max_acc_mps2: float
    margin_s: float = 0.05

    def __post_init__(self) -> None:
        for name in ("max_speed_mps", "max_acc_mps2"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ParameterError(f"{name} = {value}: expected a finite value > 0")
        if not (np.isfinite(self.margin_s) and self.margin_s >= 0):
            raise ParameterError(f"margin_s = {self.margin_s}: expected a finite value >= 0")


@dataclass(frozen=True)
class Failure:
    """One failure: frames ``[first, last]`` of a recording and the joints that failed."""

    first: int
    last: int
    joints: str


def _breaks(rec: Recording, c: Ceilings, delta_y_m: float) -> tuple[np.ndarray, np.ndarray]:
    """``(T, J)`` frames that break a ceiling, and ``(T, J)`` frames still moving fast."""
    y, t = rec.positions_m, rec.times_s
    dt = np.diff(t)
    speed = np.linalg.norm(np.diff(y, axis=0), axis=-1) / dt[:, None]  # (T-1, J)
    fast = np.zeros(y.shape[:2], bool)  # a frame reached or left faster than half the ceiling
    fast[1:] |= speed > 0.5 * c.max_speed_mps
    fast[:-1] |= speed > 0.5 * c.max_speed_mps
    broken = np.zeros(y.shape[:2], bool)
    broken[1:] |= speed > c.max_speed_mps
    broken[:-1] |= speed > c.max_speed_mps
    if len(t) > 2:
        dt2 = dt[1:] * dt[:-1]
        second = np.linalg.norm(y[2:] - 2.0 * y[1:-1] + y[:-2], axis=-1) / dt2[:, None]
        broken[1:-1] |= second > c.max_acc_mps2 + 4.0 * delta_y_m / dt2[:, None]
    return broken, fast | broken


def runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """``[(a, b)]``: the half-open runs of True in ``mask (T,)``."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(edges[::2].tolist(), edges[1::2].tolist()))


def find_failures(rec: Recording, c: Ceilings, delta_y_m: float) -> list[Failure]:
    """The reconstruction failures of ``rec`` (see the module notes), in time order; failures
    that touch are one."""
    broken, fast = _breaks(rec, c, delta_y_m)
    T = rec.n_frames
    dt = max(float(np.median(np.diff(rec.times_s))), 1e-9)
    pad = int(np.ceil(c.margin_s / dt - 1e-6))  # frames: 0.05 s at 120 Hz is 6, not 7
    failed = np.zeros(broken.shape, bool)  # (T, J): in a fast run of a joint that broke one
    for j in np.flatnonzero(broken.any(axis=0)):
        for a, b in runs(fast[:, j]):
            if broken[a:b, j].any():
                failed[max(a - pad, 0) : min(b + pad, T), j] = True
    out = []
    for a, b in runs(np.asarray(failed.any(axis=1))):
        joints = ", ".join(rec.joints[j] for j in np.flatnonzero(failed[a:b].any(axis=0)))
        out.append(Failure(a, b - 1, joints))
    return out


def pieces(rec: Recording, failures: list[Failure], min_frames: int = 2) -> list[Recording]:
    """``rec`` without its failures: the pieces between them (at least ``min_frames`` each),
    named ``name@start-end s``."""
    if not failures:
        return [rec]
    keep = np.ones(rec.n_frames, bool)
    for f in failures:
        keep[f.first : f.last + 1] = False
    out = []
    for a, b in runs(keep):
        if b - a >= min_frames:
            t = rec.times_s
            out.append(Recording(f"{rec.name}@{t[a]:.2f}-{t[b - 1]:.2f}s", rec.kind, t[a:b],
                                 rec.positions_m[a:b], rec.source))  # fmt: skip
    return out


def describe(rec: Recording, failures: list[Failure]) -> list[str]:
    """One line per failure: its time span, frames and the joints that broke a ceiling."""
    t = rec.times_s
    return [
        f"{rec.name}: {t[f.first]:.2f}-{t[f.last]:.2f} s ({f.last - f.first + 1} frames), "
        f"{f.joints}"
        for f in failures
    ]


def split(
    rec: Recording, ceilings: Ceilings | None, delta_y_m: float
) -> tuple[list[Recording], list[Failure]]:
    """``rec``'s pieces without its failures under ``ceilings`` (None: ``rec`` whole), and the
    failures."""
    if ceilings is None:
        return [rec], []
    failures = find_failures(rec, ceilings, delta_y_m)
    return pieces(rec, failures), failures
