"""Verdict delivery and command loss at a bus subscriber, idle and with the REST service serving
many event streams (``sara-app bench --sse``).

As in ``serve``: the zenoh router and the cell worker in processes of their own, the REST service
(registry + uvicorn) in this one. A probe process subscribes to the cell's verdicts and commands
and measures, per message, reception time minus the message's stamp (same clock), and counts the
commands' sequence gaps (lost commands). A verdict's stamp is its cycle's time, which leads the
clock by up to a period after a late cycle (``CellWorker.step``): on a loaded machine the median
can be below 0, and then says the worker ran ahead of the clock, not that delivery was free.
Phases alternate: idle, then ``clients`` Server-Sent Event streams
(``/api/cells/<cell>/events``, 20 Hz each) read by threads of this process.
"""

from __future__ import annotations

import http.client
import json
import subprocess
import sys
import threading
import time

from sara_app.bus.heartbeat import Heartbeat
from sara_app.bus.session import Bus, free_port

PROBE = """
import json, sys, time, zenoh
import numpy as np
port, cell, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
conf = {"mode": "client", "connect": {"endpoints": [f"tcp/127.0.0.1:{port}"]}}
lat, seqs = [], []
def on_v(s):
    lat.append(time.time() - json.loads(s.payload.to_bytes())["stamp_s"])
def on_c(s):
    p = s.payload.to_bytes()  # a compact record (seq at byte 16) or JSON
    seqs.append(int.from_bytes(p[16:24], "little") if p[:1] == b"\\x00" else json.loads(p)["seq"])
with zenoh.open(zenoh.Config.from_json5(json.dumps(conf))) as z:
    a = z.declare_subscriber(f"sara/{cell}/verdict", on_v)
    b = z.declare_subscriber(f"sara/{cell}/robot/command", on_c)
    time.sleep(seconds)
    a.undeclare(); b.undeclare()
d = np.diff(np.array(seqs)) if len(seqs) > 1 else np.zeros(0)
print(json.dumps({"p50": float(np.percentile(lat, 50)), "p99": float(np.percentile(lat, 99)),
                  "n": len(lat), "commands": len(seqs), "lost": int(np.sum(d[d > 1] - 1))}))
"""

Row = tuple[str, float, float, str]


def _streams(port: int, cell: str, n: int, stop: threading.Event) -> list[threading.Thread]:
    def read() -> None:
        conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
        conn.request("GET", f"/api/cells/{cell}/events?interval_s=0.05")
        resp = conn.getresponse()
        while not stop.is_set() and resp.readline():
            pass
        conn.close()

    threads = [threading.Thread(target=read, daemon=True) for _ in range(n)]
    for t in threads:
        t.start()
    return threads


def _probe(port: int, cell: str, seconds: float) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", PROBE, str(port), cell, str(seconds)],
        capture_output=True, text=True, timeout=seconds + 60,
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def bench_sse_load(clients: int = 50, seconds: float = 5.0, rounds: int = 2) -> list[Row]:
    """Rows: verdict delivery p50/p99 (us) idle and with ``clients`` event streams."""
    from sara_app.api import ApiServer, CellRegistry, create_app
    from sara_app.processes.serve import ROUTER, WORKER, spawn_cell_process, start_process

    zp, ap = free_port(), free_port()
    cell = "ssebench"
    router = start_process([sys.executable, "-m", ROUTER, "--port", str(zp)])
    procs = [router]
    results: dict[str, list[dict]] = {"idle": [], "sse": []}
    try:
        time.sleep(1.0)
        procs.append(spawn_cell_process(WORKER, cell, "empty_cell", zp))
        with Bus.client(zp) as bus, Heartbeat(bus, cell):
            reg = CellRegistry(bus).start()
            api = ApiServer(create_app(reg, static_dir=None), port=ap)
            api.start()
            try:
                t_end = time.monotonic() + 60
                while not (reg.cell(cell) or {}).get("online"):
                    if time.monotonic() > t_end:
                        raise RuntimeError("the worker did not come up")
                    time.sleep(0.1)
                for _ in range(rounds):
                    results["idle"].append(_probe(zp, cell, seconds))
                    stop = threading.Event()
                    threads = _streams(ap, cell, clients, stop)
                    time.sleep(0.5)
                    results["sse"].append(_probe(zp, cell, seconds))
                    stop.set()
                    for t in threads:
                        t.join(5)
            finally:
                api.stop()
                reg.close()
    finally:
        for p in reversed(procs):
            p.terminate()
            p.wait(10)
    rows: list[Row] = []
    for name, label in (("idle", "idle"), ("sse", f"{clients} SSE clients")):
        r = results[name]
        p50 = 1e6 * sum(x["p50"] for x in r) / len(r)
        p99 = 1e6 * max(x["p99"] for x in r)
        lost = sum(x["lost"] for x in r)
        sent = sum(x["commands"] for x in r)
        rows.append((f"verdict delivery to a bus subscriber, {label}", p50, p99,
                     f"commands lost {lost} of {sent + lost}"))  # fmt: skip
    return rows
