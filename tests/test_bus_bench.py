"""The latency benchmark of ``sara-app bench`` (skeleton publication -> verdict reception through
a router and a worker process): it matches verdicts to the skeletons they used. No timing
assertions: only that it measures what it says."""

from __future__ import annotations

import math

from sara_app.bench.bus import bench_latency


def test_latency_rows_match_every_control_period() -> None:
    rows = bench_latency(n=40, rate_hz=120.0, dts_s=(0.004, 0.002))
    assert [r[0] for r in rows] == [
        "skeleton -> verdict, 120 Hz in, dt 4 ms",
        "skeleton -> verdict, 120 Hz in, dt 2 ms",
        "skeleton -> verdict, 10000 msg/s flood on another id, dt 4 ms",
    ]
    for _, p50, p99, note in rows:
        assert math.isfinite(p50) and 0 < p50 <= p99, note
        matched = int(note.split(" matched")[0].split()[-1].split("/")[0])
        assert matched >= 30, note  # nearly every skeleton is answered by a verdict
