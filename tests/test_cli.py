"""The command line answers --help without loading the numerical kernels or the web stack
(issue: `sara-app --help` took 3.4 s importing them), and lists its defaults."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

HEAVY = ("numba", "fastapi", "viser", "pinocchio", "zenoh", "scipy")


@pytest.mark.parametrize("argv", [["--help"], ["serve", "--help"], ["reach", "--help"]])
def test_help_imports_nothing_heavy(argv: list[str]) -> None:
    code = (
        "import sys\nfrom sara_app.cli import main\ntry:\n    main(sys.argv[1:])\n"
        "except SystemExit:\n    pass\n"
        f"print(sorted(m for m in {HEAVY!r} if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True,
                         timeout=60, check=True).stdout  # fmt: skip
    assert out.strip().splitlines()[-1] == "[]", out[-500:]


def test_serve_help_shows_its_defaults() -> None:
    out = subprocess.run([sys.executable, "-m", "sara_app.cli", "serve", "--help"],
                         capture_output=True, text=True, timeout=60, check=True).stdout  # fmt: skip
    out = " ".join(out.split())  # argparse wraps lines
    for text in ("default: 7447", "default: 8080", "default: 8000", "default: punches",
                 "default: cell1"):  # fmt: skip
        assert text in out, out


def test_worker_and_controller_pass_the_robot_encoding_on() -> None:
    """``sara-app worker`` / ``controller`` hand ``--robot-encoding`` to the process (default
    compact); an unknown encoding is refused by the parser."""
    from sara_app.cli import build_parser
    from sara_app.commands.serve import _process_argv

    ap = build_parser()
    for name in ("worker", "controller"):
        argv = _process_argv(ap.parse_args([name, "--robot-encoding", "json"]))
        assert argv[-2:] == ["--robot-encoding", "json"]
        assert _process_argv(ap.parse_args([name]))[-2:] == ["--robot-encoding", "compact"]
        with pytest.raises(SystemExit):
            ap.parse_args([name, "--robot-encoding", "msgpack"])


def test_a_worker_started_by_hand_records_what_it_answers(tmp_path: Path) -> None:
    """``sara-app worker`` (a cell joined to a running router by hand) keeps the same record
    as serve's workers: a retirement sent to it on the bus is in this machine's audit log."""
    import os
    import time

    from sara_app.bus import keys
    from sara_app.bus.messages import ParamsAckMsg, RetireMsg
    from sara_app.bus.session import Bus, free_port
    from sara_app.ops.audit import AuditLog

    port = free_port()
    env = {**os.environ, "SARA_APP_DATA": str(tmp_path)}
    cmd = [sys.executable, "-m", "sara_app.cli", "worker", "--cell", "hand1", "--scenario",
           "empty_cell", "--zenoh-port", str(port), "--duration", "30"]  # fmt: skip
    with Bus.router(port), Bus.client(port) as bus:
        acks = bus.subscribe(keys.params_ack_key("hand1"), fifo=True)
        status = bus.subscribe(keys.status_key("hand1"))
        proc = subprocess.Popen(cmd, env=env)
        try:
            t_end = time.monotonic() + 60
            while not any(
                getattr(d.msg, "state", "") == "running" for d in status.drain().messages
            ):
                assert proc.poll() is None and time.monotonic() < t_end, "worker did not run"
                time.sleep(0.05)
            pub = bus.publisher(keys.retire_key("hand1"))
            pub.put(RetireMsg(seq=1, stamp_s=time.time(), request_id="r-hand", human_id="nobody",
                              user="tester"))  # fmt: skip
            answered = False
            while not answered:
                assert time.monotonic() < t_end, "no answer"
                answered = any(isinstance(d.msg, ParamsAckMsg) and d.msg.request_id == "r-hand"
                               for d in acks.drain().messages)  # fmt: skip
                time.sleep(0.02)
            rows: list[dict] = []
            while not rows and time.monotonic() < t_end:
                time.sleep(0.1)
                path = tmp_path / "audit.sqlite"
                rows = AuditLog(path).worker_answers("hand1") if path.exists() else []
        finally:
            proc.terminate()
            proc.wait(20)
    assert [(r["request"], r["request_id"], r["user"], r["outcome"]) for r in rows] == [
        ("retire", "r-hand", "tester", "refused")
    ]
