"""How many threads zenoh runs a process's I/O on.

zenoh starts its runtimes once per process, with the first session, in the layout its
``ZENOH_RUNTIME`` environment variable names (RON: each of ``app``, ``acc``, ``tx``, ``rx``,
``net`` with ``worker_threads`` or a ``handover`` to another); by default a runtime per role,
so a message crossing a process wakes two or three of its threads in turn, each a context switch
on the cell's few cores. :data:`ONE_IO_THREAD` hands them all over to one thread: the receive,
the routing and the send of a message then run on the thread that read it.

That thread must never block. A FIFO subscription blocks the thread that delivers into its full
queue until the loop drains it (back-pressure), so with one thread every message of the process,
commands included, would wait for the drain. A process asks for the one thread only when it
has no FIFO subscription (:func:`use_one_io_thread`: the reference controller), and
:func:`refuse_fifo` makes a FIFO subscription in such a process an error, not a stall. The cell
worker and the replayer have none any more (their requests wait in
:mod:`~sara_app.bus.request_queue`'s queues) but keep zenoh's default threads: with the worker
on one thread, a flood of 5 000 retirements delayed its commands and states on that thread long
enough for the controller to brake on its own, and the cell stayed on a tracking fault for
0.7 s after the flood (``test_a_flood_of_retirements_holds_up_none_of_the_workers_other_inputs``
failed 2 of 2 in a run of three test files; it passes on zenoh's default threads). The chaos
soak's failure first blamed on the one thread was a router stall (docs/performance.md).

Not the router: it waits for room in the queue towards each subscriber (1 ms before it drops a
message, longer for a declaration), so one client that stops reading (a frozen observer) made
a router on one thread wait on every message and stop the whole bus, 10-15 s into the stall in
a cell at 500 Hz; on zenoh's default threads the cell went on (docs/performance.md).
"""

from __future__ import annotations

import os

from sara_app.errors import SaraError

ZENOH_RUNTIME_ENV = "ZENOH_RUNTIME"
ONE_IO_THREAD = (
    "(app: (worker_threads: 1), rx: (handover: app), tx: (handover: app), "
    "net: (handover: app), acc: (handover: app))"
)
"""Every zenoh runtime of the process handed over to one with a single worker thread.
``sara-app bench --live`` (docs/performance.md, 2026-12-04): the controller's context switches
per control cycle 5.1 -> 3.0."""

_first_layout: list[str | None] = []
"""The layout in force when this process opened its first session (zenoh reads it then)."""


def use_one_io_thread() -> bool:
    """Ask for :data:`ONE_IO_THREAD` for this process (and the children it starts), unless the
    environment already names a layout (an operator's ``ZENOH_RUNTIME`` is kept) or a session
    was opened already (too late: zenoh's threads run). Returns whether it asked."""
    if ZENOH_RUNTIME_ENV in os.environ or _first_layout:
        return False
    os.environ[ZENOH_RUNTIME_ENV] = ONE_IO_THREAD
    return True


def note_session() -> None:
    """Called before each session is opened: records the layout of the first."""
    if not _first_layout:
        _first_layout.append(os.environ.get(ZENOH_RUNTIME_ENV))


def one_io_thread() -> bool:
    """Whether this process's zenoh I/O runs on :data:`ONE_IO_THREAD`."""
    return bool(_first_layout) and _first_layout[0] == ONE_IO_THREAD


def refuse_fifo(key_expr: str) -> None:
    """Raise :class:`SaraError` when a FIFO subscription to ``key_expr`` would block this
    process's only I/O thread (module doc)."""
    if one_io_thread():
        raise SaraError(
            f"a FIFO subscription to {key_expr!r} in a process whose zenoh I/O runs on one "
            "thread: a full queue would hold every message of the process; subscribe with a "
            "ring (fifo=False) or open the first session without use_one_io_thread()"
        )
