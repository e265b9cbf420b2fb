"""The command line answers --help without loading the numerical kernels or the web stack
(issue: `sara-app --help` took 3.4 s importing them), and lists its defaults."""

from __future__ import annotations

import subprocess
import sys

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
