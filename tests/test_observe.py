"""``sara-app observe``: dashboards and API for a cell whose worker runs elsewhere (here: a worker
process on a router this test hosts, as on a router machine): the cell shows up online in the
API with a link to its own 3D view, which answers; an unknown cell is an error naming it."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
import urllib.request

from sara_app.bus.heartbeat import Heartbeat
from sara_app.bus.session import Bus, free_port
from sara_app.errors import ParameterError
from sara_app.ops.supervisor import stop_processes
from sara_app.processes.observe import announced_scenario
from sara_app.processes.serve import spawn_cell_process


def _get(url: str) -> tuple[int, bytes]:
    with urllib.request.urlopen(url, timeout=2) as r:
        return r.status, r.read()


def test_observe_shows_a_cell_running_on_another_router() -> None:
    port, vp, ap = free_port(), free_port(), free_port()
    with Bus.router(port) as hub:
        worker = spawn_cell_process("sara_app.runtime.worker", "far1", "empty_cell", port)
        beat = Heartbeat(hub, "far1").start()
        proc = subprocess.Popen(
            [sys.executable, "-m", "sara_app.cli", "observe", "--cell", "far1", "--zenoh-port",
             str(port), "--viewer-port", str(vp), "--api-port", str(ap), "--duration", "90"],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )  # fmt: skip
        try:
            cell = None
            t_end = time.monotonic() + 90
            while time.monotonic() < t_end and proc.poll() is None:
                try:
                    cells = json.loads(_get(f"http://127.0.0.1:{ap}/api/cells")[1])
                    cell = next((c for c in cells if c["cell"] == "far1" and c["online"]), None)
                except OSError:
                    pass
                if cell:
                    break
                time.sleep(0.5)
            assert cell is not None and cell["scenario"] == "empty_cell"
            links = json.loads(_get(f"http://127.0.0.1:{ap}/api/links")[1])
            assert _get(links["viewers"]["far1"])[0] == 200
            assert json.loads(_get(f"http://127.0.0.1:{ap}/api/processes")[1]) == {}
        finally:
            proc.send_signal(signal.SIGINT)
            out = proc.communicate(timeout=30)[0]
            beat.stop()
            stop_processes([worker])
        assert proc.returncode == 0, out
        try:
            announced_scenario(hub, "nobody", wait_s=0.5)
            raise AssertionError("an unknown cell must be an error")
        except ParameterError as e:
            assert "'nobody'" in str(e)
