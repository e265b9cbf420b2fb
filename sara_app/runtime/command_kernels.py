"""A cycle's robot command as one compiled call: the compact record's body (the set point and
the held verified stop after it, :class:`~sara_app.bus.compact.CommandArrays`) from the
follower's set point and the held stop, with the schema's value checks on the way.

It was a dozen numpy calls (a mask of the held samples after the step, their offsets, stacking,
copies, a finiteness and an order check): about 24 us of a live worker's cycle, whose caches are
cold after 2 ms of sleep. The numpy version is the oracle in ``tests/test_command_kernels.py``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types

from sara_app.kernel_types import B1, F8, I8, RO1, RO2

__all__ = ["FINITE", "ORDER", "command_body"]

FINITE, ORDER = 1, 2
"""Status codes: a value is not finite / the stop's times do not increase strictly (0: good)."""


@njit(types.Tuple((I8, types.Array(F8, 1, "C")))(F8, F8, RO1, RO1, RO1, B1, RO1, RO2), cache=True)
def command_body(
    now: float,
    dt: float,
    q: Any,
    q_dot: Any,
    q_ddot: Any,
    has_stop: bool,
    held_times: Any,
    held_q: Any,
) -> Any:
    """``(status, body)``: ``body`` is ``q, q_dot, q_ddot (n each)``, then the stop's offsets
    from ``now`` ``(F,)`` and positions ``(F, n)``: the set point at ``dt``, then each held
    sample later than ``now + dt`` (absolute times ``held_times (K,)``, positions ``held_q (K,
    n)``); ``F = 0`` without a held stop (``has_stop`` False). ``status``: 0, :data:`FINITE`
    or :data:`ORDER`."""
    n = q.shape[0]
    K = held_times.shape[0] if has_stop else 0
    cut = now + dt + 1e-9
    F = 0
    if has_stop:
        F = 1
        for k in range(K):
            F += held_times[k] > cut
    body = np.empty(3 * n + F * (n + 1))
    for j in range(n):
        body[j], body[n + j], body[2 * n + j] = q[j], q_dot[j], q_ddot[j]
    if F:
        t0, q0 = 3 * n, 3 * n + F
        body[t0] = dt
        for j in range(n):
            body[q0 + j] = q[j]
        r = 1
        for k in range(K):
            if held_times[k] > cut:  # NaN: not later (and refused below if it were kept)
                body[t0 + r] = held_times[k] - now
                for j in range(n):
                    body[q0 + r * n + j] = held_q[k, j]
                r += 1
    status = 0
    for i in range(body.shape[0]):
        if not math.isfinite(body[i]):
            status = FINITE
            break
    if status == 0:
        for r in range(1, F):
            if not body[3 * n + r] > body[3 * n + r - 1]:
                status = ORDER
                break
    return status, body
