"""The worker's own record of the requests it answers: every scenario edit, retirement and
re-plan, whoever sent it, into the audit log (:meth:`~sara_app.ops.audit.AuditLog.
record_worker_answers`, table ``worker_answers``).

The API and the dashboard audit what their users ask; a program that logs in on the bus as an
editor (any process holding the credentials file) sends the same messages straight to the
worker, and nothing recorded those. The worker is where every request takes effect, so it
records what it answered: the request, who the message says sent it, whether a loosening was
confirmed, applied or refused and why, and the configuration checksum in force after it.

The loop never waits for the database: :meth:`AnswerLedger.note` queues the row (a deque, no
lock held across a write) and a thread of its own writes the queue in one transaction every
``FLUSH_S``. At most ``MAX_QUEUED`` rows wait; beyond that (a flood of refused requests) rows
are counted as ``lost`` and logged, never silently dropped, and the first row of the next
write says how many were lost since the write before (``lost_before``). A database that cannot
be written is logged (rate-limited) and its rows counted as lost: the audit never stops the
cell. A worker killed outright (``kill -9``, a power cut) takes the rows of its last
``FLUSH_S`` with it, uncounted: the requests' senders (the API, the dashboard) keep their own
audit of what they asked.
"""

from __future__ import annotations

import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path

from sara_app.ops.audit import AuditLog, WorkerAnswer

log = logging.getLogger("sara_app.worker")

FLUSH_S = 0.2
"""How often the ledger's thread writes what the loop queued (one transaction)."""
MAX_QUEUED = 1024
"""Rows waiting at most; beyond, rows are counted as lost (a flood of requests)."""
LOG_EVERY_S = 10.0
"""A failing database or lost rows are logged at most this often."""


class AnswerLedger:
    """Rows of answered requests of cell ``cell`` into the audit log at ``path`` (opened by
    the ledger's thread: a database that cannot be opened costs the loop nothing);
    ``checksum_of()``: the configuration checksum in force (read when a row is queued)."""

    def __init__(self, path: str | Path, cell: str, checksum_of: Callable[[], str]) -> None:
        self.path = Path(path)
        self.cell = cell
        self.checksum_of = checksum_of
        self.lost = 0
        """Rows not written: the queue was full or the database failed."""
        self.written = 0
        self._lost_written = 0  # lost rows already reported in a written row
        self._queue: deque[WorkerAnswer] = deque()
        self._stop = threading.Event()
        self._logged_s = -float("inf")
        self._log: AuditLog | None = None
        self._thread = threading.Thread(target=self._run, name="answer-ledger", daemon=True)
        self._thread.start()

    def note(
        self,
        request: str,
        request_id: str,
        user: str,
        ok: bool,
        reason: str,
        confirmed: bool = False,
    ) -> None:
        """Queue one answered request (``request``: edit, retire or replan; ``user``: who its
        message names), answered ``ok`` or not with ``reason``, after its answer took effect;
        never blocks."""
        if len(self._queue) >= MAX_QUEUED:
            self.lost += 1
            self._say("audit: %d answered requests not recorded (queue full)", self.lost)
            return
        outcome = "applied" if ok else "refused"
        self._queue.append(
            WorkerAnswer(
                time.time(),
                self.cell,
                request,
                request_id,
                user,
                confirmed,
                outcome,
                reason,
                self.checksum_of(),
            )  # fmt: skip
        )

    def _run(self) -> None:
        while not self._stop.is_set():
            self._stop.wait(FLUSH_S)
            self._flush()

    def _flush(self) -> None:
        rows: list[WorkerAnswer] = []
        while self._queue:
            rows.append(self._queue.popleft())
        if not rows:
            return
        try:
            if self._log is None:
                self._log = AuditLog(self.path)
            self._log.record_worker_answers(rows, lost_before=self.lost - self._lost_written)
            self._lost_written = self.lost
            self.written += len(rows)
        except Exception as e:  # noqa: BLE001 - the audit never stops the cell (nor itself)
            self.lost += len(rows)
            self._say("audit: %d answered requests not recorded (%r)", self.lost, e)

    def _say(self, fmt: str, *args: object) -> None:
        now = time.monotonic()
        if now - self._logged_s >= LOG_EVERY_S:
            self._logged_s = now
            log.error(fmt, *args)

    def close(self) -> None:
        """Write what is queued, then stop the thread."""
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._flush()
