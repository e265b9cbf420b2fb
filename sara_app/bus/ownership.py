"""One worker per cell: a zenoh liveliness token ``sara/<cell>/worker/<session id>``.

A worker claims its cell before it commands anything: if another worker's token is alive it
refuses (``CellTakenError``, the process exits loudly). Two workers that start at the same
moment both declare, look again, and the one with the larger session id withdraws. A worker that
dies (crash, ``kill -9``, lost link) loses its token with its session, so a restarted worker
can claim the cell at once.
"""

from __future__ import annotations

import time
from typing import Any

from sara_app.bus import keys
from sara_app.bus.session import Bus, BusError

SETTLE_S = 0.05
"""How long a claimant waits before looking for a simultaneous claim."""


class CellTakenError(BusError):
    """Another worker serves the cell."""


def _holders(bus: Bus, cell: str, timeout_s: float) -> list[str]:
    key = f"{keys.ROOT}/{keys.check_name('cell', cell)}/worker/*"
    replies = bus.session.liveliness().get(key, timeout=timeout_s)
    return sorted(str(r.ok.key_expr).rsplit("/", 1)[-1] for r in replies if r.ok is not None)


def claim_cell(bus: Bus, cell: str, timeout_s: float = 1.0) -> Any:
    """The cell's token for this session (keep it: undeclaring it gives the cell up); raises
    :class:`CellTakenError` naming the other worker's session when the cell is served."""
    me = str(bus.session.zid())
    others = _holders(bus, cell, timeout_s)
    if others:
        raise CellTakenError(
            f"cell {cell!r} is already served by the worker of zenoh session {others[0]}; "
            "stop it first (one worker per cell)"
        )
    token = bus.session.liveliness().declare_token(f"{keys.ROOT}/{cell}/worker/{me}")
    time.sleep(SETTLE_S)
    rivals = [z for z in _holders(bus, cell, timeout_s) if z != me]
    if any(z < me for z in rivals):
        token.undeclare()
        raise CellTakenError(f"cell {cell!r}: another worker claimed it at the same time")
    return token
