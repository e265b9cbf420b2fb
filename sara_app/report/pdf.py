"""The evidence report as PDF: the HTML page printed by Debian's chromium (headless), where it
is installed; nothing is downloaded."""

from __future__ import annotations

import subprocess
import tempfile
from pathlib import Path

from sara_app.errors import InputError
from sara_app.ops.chromium import CHROMIUM_FLAGS, chromium_environment, chromium_path, stop_chromium

TIMEOUT_S = 120.0


def print_pdf(html_path: Path, pdf_path: Path) -> None:
    """Print ``html_path`` to ``pdf_path``; :class:`InputError` without chromium or when it
    fails."""
    exe = chromium_path()
    if exe is None:
        raise InputError(
            "a PDF needs chromium (Debian: apt-get install -y chromium); the HTML report was "
            f"written to {html_path}"
        )
    profile = tempfile.mkdtemp(prefix="sara-pdf-")
    cmd = [exe, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", "--no-pdf-header-footer",
           f"--print-to-pdf={pdf_path.resolve()}", html_path.resolve().as_uri()]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True, env=chromium_environment(profile))  # fmt: skip
    try:
        proc.wait(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        raise InputError(f"chromium did not print {html_path} within {TIMEOUT_S} s") from None
    finally:
        stop_chromium(proc, profile)  # its children too, then its profile
    if not pdf_path.exists() or pdf_path.stat().st_size == 0:
        raise InputError(f"chromium did not write {pdf_path}")
