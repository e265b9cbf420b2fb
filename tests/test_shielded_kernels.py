"""sara_app.robot.shielded_kernels: the slab of a plan is partitioned by its views; a process
that plans and checks SSM loads no kernel of PFL's checks."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import numpy as np
import pytest

from sara_app.robot.planning_kernels import OUT_LEN
from sara_app.robot.shielded_kernels import plan_size, plan_views


@pytest.mark.parametrize(("K", "L", "n"), [(1, 1, 1), (9, 8, 7), (13, 7, 6)])
def test_plan_views_partition_the_slab(K: int, L: int, n: int) -> None:
    """The six arrays of a plan are disjoint views that cover its slab exactly, with the
    shapes the kernels write."""
    slab = np.arange(plan_size(K, L, n), dtype=float)
    views = plan_views(slab, K, L, n)
    shapes = [(OUT_LEN,), (5, K + 1), (5, K + 1, n), (2, K, n), (K, L, 2, 3), (K, L)]
    assert [v.shape for v in views] == shapes
    seen = np.concatenate([v.ravel() for v in views])
    np.testing.assert_array_equal(np.sort(seen), slab)  # each element in exactly one view
    assert all(np.shares_memory(v, slab) for v in views)


def test_the_compiled_ssm_cycle_loads_no_pfl_kernel() -> None:
    """The SSM cycle replans with this module's :func:`plan_at_cap`, not with the PFL cycle's
    module: importing it (as an SSM cell's worker does) leaves PFL's checks unloaded (about
    0.3 s of a worker's start). Fails where the SSM cycle imports a PFL kernel module again."""
    code = textwrap.dedent(
        """
        import sys
        import sara_app.safety.shield
        print(sorted(m for m in sys.modules if m.startswith("sara_app.safety.pfl")
                     or m.startswith("sara_app.safety.contact")))
        """
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout
