"""The walking pieces of a recording: where the person walks, apart from where they stand and work.

A set for walking people is fitted to, and validated on, walks. Recordings of work often walk in
and out (CMU subject 62 walks to the bench, works, walks away): their walks are walking data of
another subject, which a set fitted to one walk has not seen. A piece is walking where the
pelvis's horizontal speed, a central difference over ``2 * half_window_s``, stays above
``min_speed_mps`` for at least ``min_duration_s``; each piece then takes in the frames of its
differences' windows (``half_window_s`` before and after: the frames within it of either end of
the recording have no difference of their own). The pieces keep the recording's frames
unchanged, named ``name@start-end s``.
"""

from __future__ import annotations

import numpy as np

from sara_app.errors import ParameterError
from sara_app.human.recording import Recording

MIN_SPEED_MPS = 0.6
"""Walking: the pelvis moves over the floor faster than this (a slow walk is about 0.8-1 m/s;
a person working at a bench shifts their weight at well under 0.3 m/s)."""
MIN_DURATION_S = 0.6
"""At least about one stride (two steps)."""
HALF_WINDOW_S = 0.125
"""Half the central difference's span: longer than a frame's noise, shorter than a step."""


def _half_window_frames(rec: Recording, half_window_s: float) -> int:
    t = rec.times_s
    return int(round(half_window_s / float(np.median(np.diff(t))))) if rec.n_frames > 1 else 0


def pelvis_speed(rec: Recording, half_window_s: float = HALF_WINDOW_S) -> np.ndarray:
    """``(T,)`` the pelvis's horizontal speed (m/s) by central differences over ``2 *
    half_window_s``; NaN within ``half_window_s`` of either end."""
    t = rec.times_s
    p = rec.positions_m[:, rec.joints.index("pelvis"), :2]
    w = _half_window_frames(rec, half_window_s)
    v = np.full(rec.n_frames, np.nan)
    if w >= 1 and rec.n_frames > 2 * w:
        v[w:-w] = np.linalg.norm(p[2 * w :] - p[: -2 * w], axis=1) / (t[2 * w :] - t[: -2 * w])
    return v


def walking_pieces(
    rec: Recording,
    min_speed_mps: float = MIN_SPEED_MPS,
    min_duration_s: float = MIN_DURATION_S,
    half_window_s: float = HALF_WINDOW_S,
) -> list[Recording]:
    """The pieces of ``rec`` in which the person walks (module docstring); empty when none."""
    if not (min_speed_mps > 0 and min_duration_s > 0 and half_window_s > 0):
        raise ParameterError(
            f"walking pieces: speed {min_speed_mps!r} m/s, duration {min_duration_s!r} s, half "
            f"window {half_window_s!r} s; expected positive numbers"
        )
    walking = pelvis_speed(rec, half_window_s) > min_speed_mps  # NaN: not walking
    t, n = rec.times_s, rec.n_frames
    w = _half_window_frames(rec, half_window_s)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], walking.astype(np.int8), [0]])))
    runs = [(a, b) for a, b in zip(edges[::2], edges[1::2]) if t[b - 1] - t[a] >= min_duration_s]
    merged: list[list[int]] = []
    for a, b in runs:  # with their windows; pieces that then touch are one
        a, b = max(int(a) - w, 0), min(int(b) + w, n)
        if merged and a <= merged[-1][1]:
            merged[-1][1] = b
        else:
            merged.append([a, b])
    return [Recording(f"{rec.name}@{t[a]:.2f}-{t[b - 1]:.2f}s", rec.kind, t[a:b],
                      rec.positions_m[a:b], rec.source) for a, b in merged]  # fmt: skip
