"""API costs for ``sara-app bench``: what the REST service adds per verdict and per request."""

from __future__ import annotations

import warnings

from sara_app.api.app import create_app
from sara_app.api.registry import CYCLE_WINDOW, CellRegistry
from sara_app.bench import timeit_us
from sara_app.bus import keys
from sara_app.bus.codec import decode
from sara_app.bus.messages import StatusMsg, VerdictMsg, encode

Row = tuple[str, float, float, str]


def bench_rows(n: int) -> list[tuple[str, float, float, str]]:
    """Decode + ingest of one verdict, a cell snapshot, and ``GET /api/cells`` (in process)."""
    reg = CellRegistry(None)
    key = keys.verdict_key("cell1")
    verdict = VerdictMsg(
        seq=0, stamp_s=1.0, cell="cell1", safety_mode="ssm", mode="intended",
        results={"pos": False, "vel": True, "acc": True}, skeleton_age_s={"h1": 0.01},
        min_distance_m=0.3, cycle_time_us=400.0, dropped={"out_of_order": 1},
    )  # fmt: skip
    payload = encode(verdict)
    status = StatusMsg(seq=0, stamp_s=1.0, cell="cell1", state="running", scenario="demo")
    reg.ingest(decode(keys.status_key("cell1"), encode(status)))

    def ingest() -> None:
        reg.ingest(decode(key, payload))

    rows: list[Row] = [("api: decode + ingest a verdict", *timeit_us(ingest, n), "per cycle")]
    snap = timeit_us(lambda: reg.cell("cell1"), n)
    rows.append(("api: cell snapshot", *snap, f"p50/p99 over {CYCLE_WINDOW} verdicts"))
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*httpx.*deprecated")
        from fastapi.testclient import TestClient

    with TestClient(create_app(reg, static_dir=None)) as client:
        get = timeit_us(lambda: client.get("/api/cells"), max(n // 10, 20), warmup=10)
    rows.append(("api: GET /api/cells, 1 cell", *get, "TestClient, in process"))
    return rows
