"""``starting`` statuses while a cell worker loads: the landing page and the dashboard say what
it is doing instead of "no cell" (on a fresh install the kernels compile for about a minute).

Light on purpose (the bus messages only): the worker's entry point
(:mod:`sara_app.processes.worker_start`) publishes with it while the heavy modules import, the
worker while it builds its cell.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

from sara_app.bus.messages import StatusMsg

log = logging.getLogger("sara_app.worker")

_LAST_SEQ: dict[str, int] = {}
"""Per cell, the last status seq a :class:`Starting` of this process sent."""


def last_status_seq(cell: str) -> int:
    """The last status seq this process sent for ``cell`` (-1: none): a later publisher
    continues after it (:meth:`~sara_app.bus.session.Publisher.continue_after`)."""
    return _LAST_SEQ.get(cell, -1)


class Starting:
    """A ``starting`` status of ``cell`` every ``period_s`` on ``pub`` saying ``what`` is being
    done and for how long, from ``__enter__`` until ``__exit__``."""

    def __init__(
        self, pub: Any, cell: str, scenario: str, what: str, period_s: float = 0.5
    ) -> None:
        self.pub, self.cell, self.scenario, self.what = pub, cell, scenario, what
        self.period_s = period_s
        self.t0 = time.time()
        self.done = threading.Event()
        self.thread = threading.Thread(target=self._run, name="starting", daemon=True)

    def __enter__(self) -> Starting:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.done.set()
        self.thread.join(2.0)

    def _run(self) -> None:
        self.pub.continue_after(last_status_seq(self.cell))
        while True:
            now = time.time()
            try:
                seq = _LAST_SEQ[self.cell] = self.pub.next_seq()
                self.pub.put(StatusMsg(seq=seq, stamp_s=now, cell=self.cell,
                                       state="starting", scenario=self.scenario,
                                       uptime_s=now - self.t0,
                                       detail=f"{self.what} ({now - self.t0:.0f} s)"))  # fmt: skip
            except Exception:  # noqa: BLE001 - a display heartbeat: never stops the start
                log.exception("starting status failed")
            if self.done.wait(self.period_s):
                return
