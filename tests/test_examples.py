"""The example of embedding the verification core runs as a user runs it (its own process) and
shows the shield at work: the robot moves at full speed while the person is far, slows down or
brakes when they come close, and never commands motion into them."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "embed_shield.py"


def test_embedding_the_shield_in_a_control_loop() -> None:
    out = subprocess.run(
        [sys.executable, str(EXAMPLE), "--cycles", "2500"],
        capture_output=True, text=True, timeout=300, check=True,
    ).stdout  # fmt: skip
    shares = dict(re.findall(r"(\w+) (\d+) %", out))
    assert int(shares.get("intended", 0)) > 20, out
    assert int(shares.get("failsafe", 0)) + int(shares.get("slowed", 0)) > 5, out
    assert int(shares.get("intended", 0)) - int(shares.get("slowed", 0)) > 5, out  # full speed
    closest = float(re.search(r"closest (-?[\d.]+) m", out).group(1))  # type: ignore[union-attr]
    assert closest > 0.0, out
