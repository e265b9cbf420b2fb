"""Many cells on one router: two real worker processes, the REST service's registry and the
landing page in headless chromium showing both cells running; and the many-cells load
benchmark on its smallest load (its numbers are for ``sara-app bench --cells``, not checked
here)."""

from __future__ import annotations

import os

import numpy as np
import pytest
from browser import CHROMIUM, chromium_on, wait_for

from sara_app.api import CellRegistry, create_app
from sara_app.api.server import ApiServer
from sara_app.bench.cells import bench_cells
from sara_app.bus.heartbeat import Heartbeat
from sara_app.bus.session import Bus, free_port
from sara_app.ops.supervisor import stop_processes
from sara_app.processes.serve import spawn_cell_process

CELLS = ("alpha", "beta")


@pytest.mark.skipif(not os.path.exists(CHROMIUM), reason=f"{CHROMIUM} is absent")
def test_two_workers_on_one_router_and_the_landing_page_shows_both(tmp_path) -> None:
    port = free_port()
    with Bus.router(port) as hub:
        workers = [
            spawn_cell_process("sara_app.runtime.worker", c, "empty_cell", port) for c in CELLS
        ]
        beats = [Heartbeat(hub, c).start() for c in CELLS]
        registry = CellRegistry.connect(port).start()
        api = ApiServer(create_app(registry), port=free_port())
        try:
            url = api.start()

            def both_online() -> bool:
                cells = {c["cell"]: c for c in registry.cells()}
                return all(c in cells and cells[c]["online"] for c in CELLS)

            wait_for(both_online, 180.0, "both workers to report")
            with chromium_on(url) as page:

                def page_text() -> str | None:
                    t = str(page.eval("document.body.innerText"))
                    return t if all(c in t for c in CELLS) and t.count("running") >= 2 else None

                text = wait_for(page_text, 60.0, "both cells on the page")
                assert "empty_cell" in str(text)
            sums = {c["cell"]: c["config_sha256"] for c in registry.cells()}
            assert sums["alpha"] == sums["beta"] and len(sums["alpha"]) == 64  # same scenario
        finally:
            api.stop()
            registry.close()
            for b in beats:
                b.stop()
            stop_processes(workers)


def test_the_load_benchmark_runs_its_smallest_load() -> None:
    rows = bench_cells(loads=((1, 1),), rate_hz=60.0, seconds=1.0)
    assert len(rows) == 2 and rows[0][0].startswith("1 cells x 1 people, 60 Hz")
    assert np.isfinite(rows[0][1]) and np.isfinite(rows[0][2]) and rows[0][1] > 0
    assert rows[1][0] == "largest passing load"
