"""The processes that verify nothing start without the verification's compiled kernels: the
reference controller, the router, the API and the dashboard read scenarios and show results,
and loading the kernels (numba's first compilation and about 5 ms per cached kernel) cost each
of them about a second per start (docs/performance.md, "Offline analysis and simulation").
Each module is imported, and a shipped scenario read, in a fresh interpreter."""

from __future__ import annotations

import subprocess
import sys

import pytest

LIGHT = (
    "sara_app.scenario",
    "sara_app.peers.controller",
    "sara_app.bus.router",
    "sara_app.api.app",
    "sara_app.dashboard.viewer",
)


def _loaded_after(module: str) -> list[str]:
    code = (
        f"import sys, {module}\n"
        "from sara_app.scenario import load_scenario\n"
        "load_scenario('close_worker')\n"
        "print(' '.join(sorted(m for m in sys.modules\n"
        "                      if m.endswith('kernels') or m.startswith('sara_app.sim.'))))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return out.stdout.split()


@pytest.mark.parametrize("module", LIGHT)
def test_a_process_that_verifies_nothing_loads_no_kernel_and_no_simulator(module: str) -> None:
    loaded = _loaded_after(module)
    assert set(loaded) <= {"sara_app.sim.whatif_table"}, loaded


def test_the_worker_loads_the_kernels_it_runs() -> None:
    """The check above can fail: the worker's module loads the shield's kernels."""
    loaded = _loaded_after("sara_app.runtime.worker")
    assert "sara_app.safety.ssm_cycle_kernels" in loaded and "sara_app.human.gate_kernels" in loaded
