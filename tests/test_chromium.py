"""Stopping chromium with its children: the profile folder goes once no process of the browser's
session is left (a child writing into it after the main process ended must not leave it behind),
and a child that ignores SIGTERM is killed. Real processes: a stand-in browser whose child
behaves as chromium's renderers do on SIGTERM, and Debian's chromium itself where installed."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import pytest

from sara_app.ops import chromium
from sara_app.ops.chromium import chromium_environment, chromium_path, stop_chromium

# The main process ends at once on SIGTERM; its child (same session) takes 0.3 s on SIGTERM and
# then writes into the profile, or ignores SIGTERM altogether.
BROWSER = textwrap.dedent(
    """
    import os, signal, sys, time
    profile, child_ignores = sys.argv[1], sys.argv[2] == "ignore"
    if os.fork() == 0:
        def late(*_):
            time.sleep(0.3)
            os.makedirs(profile, exist_ok=True)
            open(os.path.join(profile, "late"), "w").close()
            os._exit(0)
        signal.signal(signal.SIGTERM, signal.SIG_IGN if child_ignores else late)
        open(os.path.join(profile, "child-ready"), "w").close()
        while True:
            time.sleep(0.05)
    signal.signal(signal.SIGTERM, lambda *_: os._exit(0))
    while True:
        time.sleep(0.05)
    """
)


def _start(profile: str, child: str) -> subprocess.Popen[bytes]:
    proc = subprocess.Popen([sys.executable, "-c", BROWSER, profile, child],
                            start_new_session=True)  # fmt: skip
    t_end = time.monotonic() + 10
    while not (Path(profile) / "child-ready").exists():
        assert time.monotonic() < t_end, "the stand-in browser's child did not start"
        time.sleep(0.02)
    return proc


def _session_ended(pgid: int) -> bool:
    """No process of session ``pgid`` but zombies (read from each process's status file, not
    from the stat file the code reads)."""
    for status in Path("/proc").glob("[0-9]*/status"):
        try:
            fields = dict(line.split(":", 1) for line in status.read_text().splitlines())
        except (OSError, ValueError):
            continue  # ended meanwhile
        pgids = fields.get("NSpgid", "").split()
        if pgids and int(pgids[0]) == pgid and not fields["State"].strip().startswith("Z"):
            return False
    return True


def test_the_profile_goes_after_the_last_child_wrote_into_it() -> None:
    profile = tempfile.mkdtemp(prefix="sara-test-chromium-")
    proc = _start(profile, "late")
    stop_chromium(proc, profile)
    assert _session_ended(proc.pid)
    assert not os.path.exists(profile), os.listdir(profile)


def test_a_child_that_ignores_sigterm_is_killed(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(chromium, "STOP_TIMEOUT_S", 0.5)
    profile = tempfile.mkdtemp(prefix="sara-test-chromium-")
    proc = _start(profile, "ignore")
    t0 = time.monotonic()
    stop_chromium(proc, profile)
    assert _session_ended(proc.pid)
    assert not os.path.exists(profile)
    assert time.monotonic() - t0 < 5.0


@pytest.mark.skipif(chromium_path() is None, reason="needs Debian's chromium")
def test_chromium_leaves_no_process_and_no_folder() -> None:
    profile = tempfile.mkdtemp(prefix="sara-test-chromium-")
    exe = chromium_path()
    assert exe is not None
    proc = subprocess.Popen(
        [exe, *chromium.CHROMIUM_FLAGS, f"--user-data-dir={profile}", "about:blank"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        env=chromium_environment(profile),
    )
    t_end = time.monotonic() + 30
    while len(os.listdir(profile)) < 2:  # chromium has made its profile (and children)
        assert time.monotonic() < t_end, "chromium wrote no profile"
        time.sleep(0.1)
    time.sleep(1.0)
    stop_chromium(proc, profile)
    assert _session_ended(proc.pid)
    assert not os.path.exists(profile)
