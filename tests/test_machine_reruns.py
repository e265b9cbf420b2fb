"""The reruns of period tests (tests/conftest.py): an ``exclusive`` test that fails while the
host took at least ``STEAL_SHARE`` of a CPU, or while a witness saw a CPU stall for at least
``WITNESS_STALL_S``, runs again, at most ``RERUNS`` times, and the last run stands; a failure
with less stolen and no such stall, or of a test that is not ``exclusive``, stands at once;
every rerun is listed. Run on a copy of the conftest in a pytest of its own, with the steal
counter and the witnesses replaced by ones whose readings the test sets (the machine's are
whatever the host does; tests/test_stalls.py checks the real witness)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

TESTS = """
import os
import pytest

def _runs(name):
    path = os.path.join(os.environ["COUNTS"], name)
    n = int(open(path).read()) if os.path.exists(path) else 0
    open(path, "w").write(str(n + 1))
    return n + 1

@pytest.mark.exclusive
def test_fails_once():
    assert _runs("once") >= 2

@pytest.mark.exclusive
def test_always_fails():
    _runs("always")
    assert False

def test_plain_fails_once():
    assert _runs("plain") >= 2
"""


def _run(
    tmp_path: Path, stolen_s_per_read: float, stall_s: float = 0.0
) -> tuple[str, dict[str, int]]:
    conftest = (Path(__file__).parent / "conftest.py").read_text()
    fake = f"""
_steal_calls = [0]
def _steal_s():
    _steal_calls[0] += 1
    return [{stolen_s_per_read} * _steal_calls[0]]

class _FakeWitnesses:
    def stop(self):
        from sara_app.ops.stalls import Stall
        return [Stall(0, 0.0, {stall_s})] if {stall_s} > 0 else []

def _witnesses():
    return _FakeWitnesses()
"""
    (tmp_path / "conftest.py").write_text(conftest + fake)
    (tmp_path / "test_periods.py").write_text(TESTS)
    counts = tmp_path / "counts"
    counts.mkdir()
    out = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-n", "0", "-p", "no:cacheprovider",
         "-W", "ignore::pytest.PytestUnknownMarkWarning", str(tmp_path)],
        capture_output=True, text=True, timeout=120, cwd=tmp_path,
        env={**os.environ, "COUNTS": str(counts)},
    ).stdout  # fmt: skip
    runs = {p.name: int(p.read_text()) for p in counts.iterdir()}
    return out, runs


def test_a_failure_while_the_host_took_the_cpu_runs_again(tmp_path: Path) -> None:
    out, runs = _run(tmp_path, 10.0)  # 10 s stolen per read: far over 1 % of any run
    assert runs == {"once": 2, "always": 3, "plain": 1}, (runs, out)
    assert "2 failed, 1 passed" in out, out
    assert out.count("rerun (the machine, not the cell)") == 3, out  # 1 + 2, all listed
    assert "test_fails_once: run 1 failed while the host took" in out


def test_a_failure_with_nothing_stolen_stands(tmp_path: Path) -> None:
    out, runs = _run(tmp_path, 0.0)
    assert runs == {"once": 1, "always": 1, "plain": 1}, (runs, out)
    assert "3 failed" in out and "rerun" not in out, out


def test_a_failure_while_a_cpu_stalled_runs_again(tmp_path: Path) -> None:
    out, runs = _run(tmp_path, 0.0, stall_s=0.004)  # nothing stolen, a CPU 4 ms late
    assert runs == {"once": 2, "always": 3, "plain": 1}, (runs, out)
    assert "2 failed, 1 passed" in out, out
    assert "test_fails_once: run 1 failed while the host took 0.0 % of a CPU and a CPU " \
        "stalled 4.0 ms" in out, out  # fmt: skip


def test_a_failure_with_a_stall_shorter_than_the_threshold_stands(tmp_path: Path) -> None:
    out, runs = _run(tmp_path, 0.0, stall_s=0.0009)
    assert runs == {"once": 1, "always": 1, "plain": 1}, (runs, out)
    assert "3 failed" in out and "rerun" not in out, out
