"""``sara-app serve`` as a user starts it: everything comes up on 127.0.0.1, the cell is live in
the API, the 3D view is served, and Ctrl-C (SIGINT) stops every process."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
import urllib.request

from sara_app.bus.session import free_port


def _get(url: str) -> tuple[int, bytes]:
    with urllib.request.urlopen(url, timeout=2) as r:
        return r.status, r.read()


def test_serve_runs_the_default_cell_and_stops_on_ctrl_c() -> None:
    zp, vp, ap = free_port(), free_port(), free_port()
    cmd = [sys.executable, "-m", "sara_app.cli", "serve", "--zenoh-port", str(zp),
           "--viewer-port", str(vp), "--api-port", str(ap)]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        cell = None
        t_end = time.monotonic() + 60
        while time.monotonic() < t_end and proc.poll() is None:
            try:
                _, body = _get(f"http://127.0.0.1:{ap}/api/cells")
                cells = json.loads(body)
                if cells and cells[0].get("online") and cells[0].get("humans"):
                    cell = cells[0]
                    break
            except OSError:
                pass
            time.sleep(0.5)
        assert cell is not None, "the cell never came online in the API"
        assert cell["cell"] == "cell1" and cell["mode"] in ("intended", "failsafe", "rest")
        status, page = _get(f"http://127.0.0.1:{vp}/")
        assert status == 200 and b"<html" in page.lower()
        status, _ = _get(f"http://127.0.0.1:{ap}/")
        assert status == 200
    finally:
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, out
    assert f"http://127.0.0.1:{vp}" in out
    # the worker and replayer are gone: nobody answers on the zenoh port any more
    import socket

    with socket.socket() as s:
        s.settimeout(1)
        assert s.connect_ex(("127.0.0.1", zp)) != 0
