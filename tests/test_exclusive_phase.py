"""The suite's two-phase schedule (exclusive_phase.py), driven as xdist's controller drives it:
two workers that run their queue's head only while another test follows it (or when told to
stop), reporting each test done. Every test runs once; every exclusive test runs on one worker,
in collection order, after every light test was handed out; once the first exclusive test has
started, at most the other worker's last light test starts (conftest.py's lock keeps them
apart)."""

from __future__ import annotations

from pathlib import Path

import pytest
from exclusive_phase import ExclusiveLastScheduling, read_exclusive_ids, write_exclusive_ids

SENT: list[int] = []  # every index handed to a worker, in order


class _Node:
    def __init__(self, name: str) -> None:
        self.name, self.queue, self.shutting_down = name, [], False
        self.gateway = type("G", (), {"id": name})()

    def send_runtest_some(self, indices: list[int]) -> None:
        self.queue.extend(indices)
        SENT.extend(indices)

    def shutdown(self) -> None:
        self.shutting_down = True

    def send_steal(self, indices: list[int]) -> None:
        self.stolen = [i for i in indices if i in self.queue[1:]]  # never the running one
        self.queue = [i for i in self.queue if i not in self.stolen]


def _run(
    tmp_path: Path, names: list[str], exclusive: list[str], steps: list[int], workers: int = 2
) -> list:
    SENT.clear()
    write_exclusive_ids(str(tmp_path), "gw0", exclusive)
    tx = [f"{workers}*popen"]
    config = type("C", (), {"getvalue": lambda self, k: tx if k == "tx" else None})()
    log = type("L", (), {"workstealsched": staticmethod(lambda *a: None)})()
    sched = ExclusiveLastScheduling(config, log=log, folder=str(tmp_path))
    nodes = [_Node(f"gw{i}") for i in range(workers)]
    for n in nodes:
        sched.add_node(n)  # type: ignore[arg-type]
        sched.add_node_collection(n, names)  # type: ignore[arg-type]
    sched.schedule()
    ran: list[tuple[str, str]] = []
    k = 0
    while not (sched.tests_finished and not any(n.queue for n in nodes)):
        if sched.tests_finished:  # the controller stops every worker: each runs what it holds
            for n in nodes:
                n.shutdown()
        node = nodes[steps[k % len(steps)] % workers]
        k += 1
        assert k < 10_000, "the schedule never finishes"
        if getattr(node, "stolen", None) is not None:
            sched.remove_pending_tests_from_node(node, node.stolen)  # type: ignore[arg-type]
            node.stolen = None
            continue
        if node.queue and (len(node.queue) >= 2 or node.shutting_down):
            i = node.queue.pop(0)
            ran.append((node.name, names[i]))
            sched.mark_test_complete(node, i)  # type: ignore[arg-type]
    return ran


@pytest.mark.parametrize("steps", [[0, 1], [1, 0], [0, 0, 1], [1, 1, 1, 0], [0, 1, 1, 1, 1, 1, 1]])
def test_exclusive_tests_run_last_on_one_worker_and_every_test_once(
    tmp_path: Path, steps: list[int]
) -> None:
    names = [f"t{i}" for i in range(40)]
    exclusive = [names[i] for i in (0, 3, 4, 17, 30, 39)]
    ran = _run(tmp_path, names, exclusive, steps)
    assert sorted(n for _, n in ran) == sorted(names)
    excl = [(w, n) for w, n in ran if n in exclusive]
    assert len({w for w, _ in excl}) == 1
    assert [n for _, n in excl] == exclusive  # in collection order
    # every light test was handed out before the first exclusive one; after the first exclusive
    # test started, only the other worker's last light test can start (the lock then keeps
    # the two apart)
    sent = [names[i] for i in SENT]
    first_sent = min(sent.index(n) for n in exclusive)
    assert all(n in exclusive for n in sent[first_sent:]), sent[first_sent:]
    first = ran.index(excl[0])
    late = [(w, n) for w, n in ran[first + 1 :] if n not in exclusive]
    assert len(late) <= 1 and all(w != excl[0][0] for w, _ in late), ran[first:]


def test_without_exclusive_ids_or_light_tests_nothing_is_held(tmp_path: Path) -> None:
    assert read_exclusive_ids(str(tmp_path)) is None
    names = ["a", "b", "c"]
    ran = _run(tmp_path, names, names, [0, 1])
    assert sorted(n for _, n in ran) == names


@pytest.mark.parametrize("workers", [1, 2])
@pytest.mark.parametrize("light", [1, 2, 3])
def test_a_few_tests_on_few_workers_all_run(tmp_path: Path, workers: int, light: int) -> None:
    """A file or two with an exclusive test (``pytest -n 1 tests/test_soak.py``: its one light
    test handed out at once left no test to steal, and the base class stopped the idle worker
    with the exclusive test still held: "no active workers")."""
    names = ["x0", *(f"t{i}" for i in range(light)), "x1"]
    ran = _run(tmp_path, names, ["x0", "x1"], [0, 1], workers)
    assert sorted(n for _, n in ran) == sorted(names)
    assert [n for _, n in ran if n.startswith("x")] == ["x0", "x1"]
