"""Debian's headless chromium (never downloaded): where it is, how it is started, and how it is
stopped with every process it started before its profile folder is removed.

Used by ``sara-app bench --view`` (a browser on the live dashboard), the evidence report's PDF
and the browser tests."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import time

CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--window-size=960,600",
)
STOP_TIMEOUT_S = 10.0  # SIGTERM, then this long for the session to end, then SIGKILL


def chromium_environment(profile: str) -> dict[str, str]:
    """This process's environment with chromium's temporary files inside its ``profile``:
    the folder of its singleton socket (``org.chromium.Chromium.*``) is otherwise made in
    /tmp and left there when chromium is stopped (231 had piled up on the development VM)."""
    return {**os.environ, "TMPDIR": profile}


def chromium_path() -> str | None:
    """Debian's chromium, if installed (never downloaded)."""
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    return "/usr/bin/chromium" if os.path.exists("/usr/bin/chromium") else None


def _session_alive(pgid: int) -> bool:
    """Whether a process of session ``pgid`` still runs: a zombie (ended, its parent gone, not
    yet reaped by init, which here takes up to a second) writes nothing and does not count."""
    try:
        entries = os.listdir("/proc")
    except OSError:  # no procfs: the kernel's word, zombies counting
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return False
        return True
    for entry in entries:
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat", "rb") as f:
                stat = f.read()
        except OSError:
            continue  # ended meanwhile
        fields = stat[stat.rindex(b")") + 2 :].split()  # after the name (it may hold spaces)
        if int(fields[2]) == pgid and fields[0] != b"Z":
            return True
    return False


def _wait_session_end(pgid: int, timeout_s: float) -> bool:
    t_end = time.monotonic() + timeout_s
    while _session_alive(pgid):
        if time.monotonic() > t_end:
            return False
        time.sleep(0.02)
    return True


def stop_chromium(proc: subprocess.Popen[bytes], profile: str) -> None:
    """Stop ``proc`` (chromium started in a session of its own, ``start_new_session``) and every
    process of that session, then remove its ``profile`` folder.

    Chromium's children (renderers, its crash handler) end a moment after the main process and
    may still write into the profile then: a folder removed as soon as the main process had
    ended was now and then left behind, emptied but recreated by them. So the folder goes once
    no process of the session is left (the group id is the main process's id); after
    :data:`STOP_TIMEOUT_S` the session is killed."""
    pgid = proc.pid
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(pgid, sig)
        except ProcessLookupError:
            pass
        try:
            proc.wait(timeout=STOP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            continue
        if _wait_session_end(pgid, STOP_TIMEOUT_S):
            break
    shutil.rmtree(profile, ignore_errors=True)
