"""``serve`` supervises its cell on real processes: a stopped (SIGSTOP) worker shows offline with
its mode unknown within two heartbeats and is killed and restarted; a killed worker is back
within seconds while the controller holds the robot on its verified stop (no command meanwhile);
a killed router is restarted and every process reconnects (the robot braked meanwhile); a second
worker for the served cell refuses to start; and ``kill -9`` of ``serve`` leaves no
process of the cell behind."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import urllib.request
from typing import Any

import pytest
from test_serve import _child_pids
from waiting import wait_until

from sara_app.bus import keys
from sara_app.bus.access import Credentials, client_auth
from sara_app.bus.messages import RobotCommandMsg
from sara_app.bus.session import Bus, free_port
from sara_app.ops.audit import default_data_dir
from sara_app.processes.defaults import DEFAULT_SCENARIO
from sara_app.scenario import load_scenario


def _api(port: int, path: str) -> Any:
    with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=2) as r:
        return json.loads(r.read())


def _until(pred: Any, seconds: float, what: str) -> Any:
    return wait_until(pred, seconds, what, every_s=0.1, tolerate=(OSError,))


@pytest.mark.stack
def test_serve_supervises_its_worker_and_leaves_nothing_behind() -> None:
    zp, vp, ap = free_port(), free_port(), free_port()
    cmd = [sys.executable, "-m", "sara_app.cli", "serve", "--zenoh-port", str(zp),
           "--viewer-port", str(vp), "--api-port", str(ap)]  # fmt: skip
    serve = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        cell = lambda: _api(ap, "/api/cells/cell1")  # noqa: E731
        _until(lambda: cell()["online"] and cell()["mode"], 90, "the cell online")
        pid = _api(ap, "/api/processes")["worker"]["pid"]

        # a hung worker: offline, mode unknown, within two heartbeats; then killed, restarted
        os.kill(pid, signal.SIGSTOP)
        t0 = time.monotonic()
        _until(lambda: not cell()["online"] and cell()["mode"] is None, 5, "offline")
        assert time.monotonic() - t0 < 2.5
        _until(lambda: _api(ap, "/api/processes")["worker"]["pid"] != pid, 10, "a new worker")
        _until(lambda: cell()["online"], 60, "online again")
        procs = _api(ap, "/api/processes")
        assert procs["worker"]["restarts"] == 1 and procs["worker"]["running"]

        # a crashed worker: no command while it is gone, back within seconds
        pid = procs["worker"]["pid"]
        creds = Credentials(default_data_dir() / "zenoh_credentials.txt")  # serve made it
        with Bus.client(zp, auth=client_auth("editor", creds)) as bus:
            cmds = bus.subscribe(keys.robot_command_key("cell1"), fifo=True, capacity=100000)
            time.sleep(0.3)
            os.kill(pid, signal.SIGKILL)
            t_kill = time.time()
            _until(lambda: _api(ap, "/api/processes")["worker"]["pid"] != pid, 10, "restart")
            _until(lambda: cell()["online"], 60, "online after the crash")
            got = [d.msg for d in cmds.drain().messages if isinstance(d.msg, RobotCommandMsg)]
        pid_after = _api(ap, "/api/processes")["worker"]["pid"]
        # the killed worker's commands, then the new one's: split where the sequence falls (by
        # stamp it is not: a cycle's time runs up to a period ahead of the clock, Worker.step,
        # and CI once saw the killed worker's last command stamped after the kill)
        k = next((i for i in range(1, len(got)) if got[i].seq < got[i - 1].seq), len(got))
        before, after = got[:k], got[k:]
        assert before and after and after[0].seq == 0  # the new worker's first command
        dt = load_scenario(DEFAULT_SCENARIO).shield.dt_s
        assert before[-1].stamp_s <= t_kill + dt  # the killed one stopped at the kill
        assert after[0].stamp_s - t_kill > 0.3  # nothing commanded while it was gone

        # a killed router: restarted; every process reconnects, the controller braked on its
        # own meanwhile, the robot moves again, and the worker still owns the cell
        router = _api(ap, "/api/processes")["router"]["pid"]
        os.kill(router, signal.SIGKILL)
        _until(lambda: _api(ap, "/api/processes")["router"]["pid"] != router, 10, "a new router")
        _until(lambda: not cell()["online"], 10, "offline while the router is gone")
        _until(lambda: cell()["online"] and cell()["mode"] == "intended", 60, "moving again")

        # the controller's own count, as the API shows it: commands stopped, it braked
        def counted() -> dict | None:  # a status after the reconnection (one a second)
            c = cell()["controller"]
            ok = c and c["online"] and c["braking_events"] >= 1 and c["worker_runs"] >= 2
            return c if ok else None

        try:
            ctl = _until(counted, 10, "the controller's counts")
        except AssertionError:
            ctl = cell()["controller"]
        # (a controller restarted by the supervisor would count from 1 again: the processes'
        # restarts say which, should this ever fail; once in CI it read 1 and 1)
        why = (ctl, {k: (v.get("restarts"), v.get("running")) for k, v in
                     _api(ap, "/api/processes").items() if isinstance(v, dict)})  # fmt: skip
        assert ctl["braking_events"] >= 1 and ctl["worker_runs"] >= 2, why
        assert _api(ap, "/api/processes")["worker"]["pid"] == pid_after  # no worker restart

        # one worker per cell: a second one refuses, loudly
        second = subprocess.run(
            [sys.executable, "-m", "sara_app.runtime.worker", "--cell", "cell1", "--port", str(zp),
             "--zenoh-user", "worker", "--zenoh-credentials", str(creds.path)],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert second.returncode == 2 and "already served" in second.stderr, second.stderr
        assert len(_child_pids(zp)) == 4  # router, controller, worker, replayer
    finally:
        serve.send_signal(signal.SIGKILL)
        serve.wait(10)
    t_end = time.monotonic() + 2.0
    while _child_pids(zp) and time.monotonic() < t_end:
        time.sleep(0.1)
    left = _child_pids(zp)
    for p in left:  # never leave them running, even when the test fails
        os.kill(p, signal.SIGKILL)
    assert not left, left
