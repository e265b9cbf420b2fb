"""The suite in two phases under pytest-xdist: the light tests spread over all the workers
(work stealing, as ``--dist worksteal``), then the tests marked ``exclusive`` one after the
other on one worker while the others have stopped.

Why: an exclusive test must run with nothing beside it (conftest.py's lock). Interleaved with
the light tests, each of the 70 waited for the test running beside it to end, with a core idle
meanwhile (about 100 s of a 726 s suite on the 2-core development VM, 2026-12-03). Run last and
together they wait for nothing. The lock stays: it is what keeps them alone, whatever the
schedule (a node that crashed gives its tests back to the light phase's queue).

The controller does not collect; the workers write the node ids of their exclusive tests to a
file the controller names (``workerinput["sara_exclusive_dir"]``) while they collect, and the
scheduler reads it when the collection is complete.
"""

from __future__ import annotations

import os
from pathlib import Path

from xdist.scheduler import WorkStealingScheduling
from xdist.scheduler.worksteal import MIN_PENDING

EXCLUSIVE_DIR_KEY = "sara_exclusive_dir"


def write_exclusive_ids(folder: str, worker_id: str, node_ids: list[str]) -> None:
    """One worker's exclusive node ids, written whole (a rename) for the controller."""
    path = Path(folder) / f"{worker_id}.txt"
    tmp = path.with_suffix(".tmp")
    tmp.write_text("".join(f"{n}\n" for n in node_ids))
    os.replace(tmp, path)


def read_exclusive_ids(folder: str) -> set[str] | None:
    """The exclusive node ids one worker wrote (all workers collect the same tests); None when
    no worker wrote them (then nothing is held back)."""
    files = sorted(Path(folder).glob("*.txt"))
    if not files:
        return None
    return {line for line in files[0].read_text().splitlines() if line}


class ExclusiveLastScheduling(WorkStealingScheduling):
    """Work stealing over the light tests; the exclusive ones held back until the light ones
    are all handed out and none is left to steal, then sent to one idle worker in collection
    order, and every other worker stopped as it runs out of tests."""

    def __init__(self, config, log=None, folder: str = "") -> None:  # type: ignore[no-untyped-def]
        super().__init__(config, log)
        self._folder = folder
        self._held: list[int] = []
        self._dispatched = False  # the exclusive tests have gone to a worker
        self._starting = False

    @property
    def tests_finished(self) -> bool:
        return not self._held and super().tests_finished

    @property
    def has_pending(self) -> bool:
        return bool(self._held) or super().has_pending

    def schedule(self) -> None:
        first = self.collection is None
        self._starting = True  # the base class hands out its whole queue at its end: not yet
        try:
            super().schedule()
        finally:
            self._starting = False
        if self.collection is None:
            return  # the workers collected different tests: the base class has said so
        if first:
            exclusive = read_exclusive_ids(self._folder) or set()
            held = [i for i, n in enumerate(self.collection) if n in exclusive]
            if len(held) < len(self.collection):  # else nothing light to run first
                self._held, kept = held, set(held)
                self.pending[:] = [i for i in self.pending if i not in kept]
        self.check_schedule()

    def check_schedule(self) -> None:
        if self._starting:
            return
        if self._dispatched and not self.pending:
            # the exclusive tests are out: never steal them; stop each worker that runs dry
            for node, pending in self.node2pending.items():
                if len(pending) < 2 and not node.shutting_down:
                    node.shutdown()
            return
        if self._held and self.pending:
            self._hand_out_pending()
        if self.pending or self.steal_requested_from_node is not None or not self._held:
            super().check_schedule()
            return
        longest = max((len(p) for p in self.node2pending.values()), default=0)
        if longest >= 3:  # work stealing still balances the light tests
            super().check_schedule()
            return
        idle = [n for n, p in self.node2pending.items() if len(p) < 2 and not n.shutting_down]
        if longest == 2 or not idle:
            return  # a worker has a light test to run before its last one: wait for it
        node = idle[0]
        held, self._held = self._held, []
        self._dispatched = True
        self.node2pending[node].extend(held)
        node.send_runtest_some(held)
        self.check_schedule()

    def _hand_out_pending(self) -> None:
        """The base class's first step only: the light tests spread over the idle workers.
        Its next step stops a worker that is still idle when nothing is left to steal, which
        with tests held back stopped the last worker (``pytest -n 1`` on a file with one light
        and one exclusive test: "no active workers"); the held tests go out here later."""
        idle = [n for n, p in self.node2pending.items()
                if len(p) < MIN_PENDING and not n.shutting_down]  # fmt: skip
        for i, node in enumerate(idle):
            self._send_tests(node, len(self.pending) // (len(idle) - i))
