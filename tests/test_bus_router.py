"""The router of a deployment on several machines: the shipped stand-alone ``zenohd``
configuration (docs/deploy/zenohd.json5) parses with the zenoh Python package, is what
``python -m sara_app.bus.router --print-config`` makes, and a router opened from it (moved to
127.0.0.1 for the test, with a real credentials file) delivers an authenticated worker's verdicts
of its cells and nothing else; a bus reachable from other machines without credentials is
refused."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from sara_app.bus.access import Credentials, client_auth
from sara_app.bus.session import Bus, BusError, endpoint, free_port
from sara_app.errors import ParameterError

DOC = Path(__file__).resolve().parent.parent / "docs" / "deploy" / "zenohd.json5"
MADE_BY = ["--cell", "cell1", "--cell", "cell2", "--listen-host", "10.0.0.2", "--port", "7447"]


def _json5_body(text: str) -> dict:
    return json.loads(re.sub(r"^\s*//.*$", "", text, flags=re.M))


def test_the_shipped_zenohd_config_is_what_the_router_prints(tmp_path: Path) -> None:
    zenoh.Config.from_file(str(DOC))  # the zenoh package reads it
    creds = Credentials.create(tmp_path / "c.txt")
    out = subprocess.run(
        [sys.executable, "-m", "sara_app.bus.router", *MADE_BY, "--credentials",
         str(creds.path), "--print-config"], capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    made = json.loads(out)
    usrpwd = made["transport"]["auth"]["usrpwd"]
    usrpwd["password"], usrpwd["dictionary_file"] = (
        "ROUTER_PASSWORD",
        "/etc/sara/zenoh_credentials.txt",
    )
    assert _json5_body(DOC.read_text()) == made
    assert made["listen"]["endpoints"] == ["tcp/10.0.0.2:7447"]
    assert (
        made["access_control"]["enabled"] and made["access_control"]["default_permission"] == "deny"
    )


def test_a_router_from_the_file_admits_its_cells_workers_only(tmp_path: Path) -> None:
    creds = Credentials.create(tmp_path / "c.txt")
    port = free_port()
    cfg = zenoh.Config.from_file(str(DOC))
    cfg.insert_json5("listen/endpoints", json.dumps([f"tcp/127.0.0.1:{port}"]))
    cfg.insert_json5("transport/auth/usrpwd/password", json.dumps(creds.password("router")))
    cfg.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(creds.path)))
    router = zenoh.open(cfg)
    try:
        with Bus.client(port, auth=client_auth("controller", creds)) as watch, \
                Bus.client(port, auth=client_auth("worker", creds)) as worker:  # fmt: skip
            got: list[str] = []
            sub = watch.session.declare_subscriber("sara/**", lambda s: got.append(str(s.key_expr)))
            t_end = time.monotonic() + 5
            while "sara/cell2/verdict" not in got and time.monotonic() < t_end:
                for cell in ("cell2", "cell3"):  # cell3 is not one of the router's cells
                    worker.session.put(f"sara/{cell}/verdict", b"{}")
                time.sleep(0.05)
            time.sleep(0.2)
            sub.undeclare()
            assert "sara/cell2/verdict" in got and "sara/cell3/verdict" not in got
        bad = {"auth": {"usrpwd": {"user": "worker", "password": "wrong-password-123"}}}
        with pytest.raises(BusError):
            Bus.client(port, timeout_ms=1500, auth=bad)
    finally:
        router.close()


def test_a_bus_beyond_this_machine_needs_credentials() -> None:
    with pytest.raises(ParameterError, match="not a loopback address"):
        endpoint(7447, "10.0.0.2")
    assert endpoint(7447, "10.0.0.2", secured=True) == "tcp/10.0.0.2:7447"
    with pytest.raises(ParameterError, match="not an IP address"):
        endpoint(7447, "router.local", secured=True)
