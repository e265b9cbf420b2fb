"""The view benchmark's accounting of cycles the worker ran late and verdicts lost."""

from __future__ import annotations

import numpy as np

from sara_app.bench.live import _missed


def _phase(stamps: list[float], seqs: list[int]) -> np.ndarray:
    return np.column_stack([np.full(len(stamps), 300.0), stamps, seqs]).astype(float)


def test_missed_cycles_and_lost_verdicts_are_told_apart() -> None:
    dt = 0.002
    on_time = _phase([10.0 + dt * k for k in range(50)], list(range(7, 57)))
    assert _missed([on_time], dt) == (0, 0)
    # the worker ran no cycle for 3 periods (its verdict numbers go on without a gap)
    stamps = [10.0 + dt * k for k in range(20)] + [10.0 + dt * k for k in range(23, 50)]
    late = _phase(stamps, list(range(47)))
    assert _missed([late], dt) == (3, 0)
    # two verdicts lost on the way (numbers missing, the periods all used)
    keep = [k for k in range(50) if k not in (5, 30)]
    lost = _phase([10.0 + dt * k for k in keep], keep)
    assert _missed([lost], dt) == (0, 2)
    assert _missed([late, lost, _phase([], [])], dt) == (3, 2)
