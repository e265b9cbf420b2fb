"""A human motion recording: the :class:`Recording` type and its checks (:func:`validate`).

A :class:`Recording` is a time series of the project's skeleton joints (see
:mod:`sara_app.human.skeleton`) in the world frame: metres, right-handed, **z up**. Formats and
loading by name: :mod:`sara_app.human.recordings` (CSV, lookup) and :mod:`sara_app.human.cmu`
(ASF/AMC).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sara_app.errors import InputError, RecordingError
from sara_app.human.skeleton import KINDS, skeleton

# --- the recording -------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Recording:
    """Joint positions over time of one skeleton kind.

    Equality and hashing are by identity (``eq=False``): field-wise ``==`` of arrays is
    ambiguous. Compare arrays with ``np.array_equal`` instead.

    ``times_s`` (T,) strictly increasing seconds; ``positions_m`` (T, J, 3) metres, world frame,
    z up, joints in the order of ``skeleton(kind).joints``. Arrays are converted to float arrays
    and checked with :func:`validate` on construction.
    """

    name: str
    kind: str
    times_s: np.ndarray
    positions_m: np.ndarray
    source: str = field(default="")

    def __post_init__(self) -> None:
        try:
            times = np.asarray(self.times_s, dtype=float)
            positions = np.asarray(self.positions_m, dtype=float)
        except (TypeError, ValueError) as exc:
            raise InputError(f"recording {self.name!r}: arrays are not numeric: {exc}") from None
        object.__setattr__(self, "times_s", times)
        object.__setattr__(self, "positions_m", positions)
        validate(self)

    @property
    def n_frames(self) -> int:
        return int(self.times_s.shape[0])

    @property
    def joints(self) -> tuple[str, ...]:
        return skeleton(self.kind).joints

    @property
    def duration_s(self) -> float:
        return float(self.times_s[-1] - self.times_s[0])

    @property
    def frame_period_s(self) -> float:
        """The median time between frames (s); needs at least two frames."""
        if self.n_frames < 2:
            raise InputError(
                f"recording {self.name!r} has {self.n_frames} frame; a frame period needs >= 2"
            )
        return float(np.median(np.diff(self.times_s)))

    def slice(self, start: int, stop: int) -> Recording:
        """Frames ``start`` to ``stop - 1`` (Python slice semantics, negative indices allowed).

        Times are kept as they are (not shifted to start at 0); arrays are copied.
        """
        idx = range(self.n_frames)[start:stop]
        if len(idx) == 0:
            raise InputError(
                f"slice [{start}:{stop}] of recording {self.name!r} is empty; "
                f"it has {self.n_frames} frames"
            )
        a, b = idx.start, idx.stop
        return Recording(
            name=self.name,
            kind=self.kind,
            times_s=self.times_s[a:b].copy(),
            positions_m=self.positions_m[a:b].copy(),
            source=f"{self.source}; frames {a}:{b}" if self.source else f"frames {a}:{b}",
        )


FRAME_INTERVAL_S = (1e-4, 0.5)
"""The frame interval a recording file may give (s; a CSV's median): a tracker at 10 kHz to
2 Hz. Times in milliseconds read as motion a thousand times slower, and a set fitted to it
would be a thousand times too small; times a million times too short put every frame of a
recording within one horizon (an analysis of T^2 pairs that does not end)."""


def check_frame_interval(step_s: float, what: str, field: str) -> None:
    """Raise :class:`RecordingError` unless ``step_s`` lies in :data:`FRAME_INTERVAL_S`;
    ``what`` names the file, ``field`` where it gives its times."""
    lo, hi = FRAME_INTERVAL_S
    if not lo <= step_s <= hi:
        raise RecordingError(
            f"{what}: its frames are {step_s:.4g} s apart ({1.0 / step_s:.4g} Hz); expected "
            f"{lo:g} to {hi:g} s, a tracker at 2 Hz to 10 kHz: is {field} in seconds (not "
            "milliseconds)?"
        )


def validate(rec: Recording) -> None:
    """Raise InputError unless ``rec`` is a well-formed recording.

    Checks: a known kind; ``times_s`` of shape (T,) with T >= 1, finite, strictly increasing;
    ``positions_m`` of shape (T, J, 3) for the kind's J joints, finite. Accepts any object with
    the attributes of :class:`Recording`.
    """
    name = getattr(rec, "name", "?")
    kind = rec.kind
    if kind not in KINDS:
        raise InputError(
            f"recording {name!r}: unknown skeleton kind {kind!r}; valid choices: {', '.join(KINDS)}"
        )
    times = np.asarray(rec.times_s)
    pos = np.asarray(rec.positions_m)
    if times.ndim != 1 or times.shape[0] < 1:
        raise InputError(
            f"recording {name!r}: times_s has shape {times.shape}; expected (T,) with T >= 1"
        )
    n_j = skeleton(kind).n_joints
    t = times.shape[0]
    if pos.shape != (t, n_j, 3):
        raise InputError(
            f"recording {name!r}: positions_m has shape {pos.shape}; expected ({t}, {n_j}, 3) "
            f"(T frames, {n_j} joints of the {kind!r} skeleton, xyz)"
        )
    if not (np.issubdtype(times.dtype, np.number) and np.issubdtype(pos.dtype, np.number)):
        raise InputError(
            f"recording {name!r}: arrays must be numeric, got {times.dtype} and {pos.dtype}"
        )
    bad_t = ~np.isfinite(times)
    if bad_t.any():
        i = int(np.argmax(bad_t))
        raise InputError(f"recording {name!r}: times_s[{i}] = {times[i]} is not finite")
    bad_p = ~np.isfinite(pos)
    if bad_p.any():
        f, j, c = (int(v) for v in np.argwhere(bad_p)[0])
        joint = skeleton(kind).joints[j]
        raise InputError(
            f"recording {name!r}: position of joint {joint!r} ({'xyz'[c]}) at frame {f} "
            f"is {pos[f, j, c]}; expected a finite number ({int(bad_p.sum())} such values)"
        )
    dt = np.diff(times)
    if (dt <= 0).any():
        i = int(np.argmax(dt <= 0))
        raise InputError(
            f"recording {name!r}: times_s not strictly increasing: times_s[{i}] = {times[i]} "
            f"then times_s[{i + 1}] = {times[i + 1]}"
        )
