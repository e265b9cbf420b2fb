"""``sara-app bench``'s display stage runs on the shipped scenarios and times both loads; the
cut leg sets it times are there (6 leg parts a person)."""

from __future__ import annotations

import math

from sara_app.bench.display import bench_rows


def test_the_display_stage_times_one_and_sixteen_people() -> None:
    rows = bench_rows(40)
    assert [r[0] for r in rows] == [
        "worker display message, 1 people",
        "worker display message, 16 people",
        "dashboard cut leg sets, 1 upper-body person",
        "dashboard cut leg sets, 16 upper-body people",
    ]
    assert all(math.isfinite(med) and 0 < med <= p99 for _, med, p99, _ in rows)
    assert rows[2][3].startswith("6 cut capsules") and rows[3][3].startswith("96 cut capsules")
