"""The event-stream load benchmark measures what it says (no timing assertions): both phases
deliver verdicts to the probe and count the commands it saw."""

from __future__ import annotations

import math

from sara_app.bench.sse import bench_sse_load


def test_both_phases_measure_verdict_delivery_and_command_loss() -> None:
    rows = bench_sse_load(clients=5, seconds=1.0, rounds=1)
    assert [r[0] for r in rows] == [
        "verdict delivery to a bus subscriber, idle",
        "verdict delivery to a bus subscriber, 5 SSE clients",
    ]
    for _, p50, p99, note in rows:
        assert math.isfinite(p50) and 0 < p50 <= p99
        lost, total = (int(x) for x in note.removeprefix("commands lost ").split(" of "))
        assert total > 100 and 0 <= lost <= total
