"""The caching rule of sara_app.kernel_types, checked on the source: no function cached on its
own (``@njit(..., cache=True)`` at module level) calls a function imported from another
sara_app module (those are built by ``_make_*`` functions with the callees' source digests in
their closure, or not cached on their own). Found when a cached helper kept an edited kernel's
old code: the PFL check then differed from its reference by 1e-9 m until the cache was
cleared."""

from __future__ import annotations

import ast
from pathlib import Path

import sara_app

ROOT = Path(sara_app.__file__).parent


def _cached(fn: ast.FunctionDef) -> bool:
    for d in fn.decorator_list:
        if isinstance(d, ast.Call) and getattr(d.func, "id", "") == "njit":
            if any(k.arg == "cache" and getattr(k.value, "value", False) for k in d.keywords):
                return True
    return False


def _imported(tree: ast.Module) -> tuple[set[str], set[str]]:
    """Names imported from other sara_app modules, and sara_app modules imported as names."""
    names, modules = set(), set()
    for node in tree.body:
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("sara_app"):
            if node.module == "sara_app.kernel_types":
                continue
            packages = (
                "sara_app",
                "sara_app.geometry",
                "sara_app.robot",
                "sara_app.safety",
                "sara_app.human",
            )
            for a in node.names:
                (modules if node.module in packages else names).add(a.asname or a.name)
    return names, modules


def test_no_cached_function_calls_kernels_of_other_files() -> None:
    offenders = []
    checked = 0
    for path in ROOT.rglob("*.py"):
        tree = ast.parse(path.read_text())
        names, modules = _imported(tree)
        for fn in tree.body:
            if not (isinstance(fn, ast.FunctionDef) and _cached(fn)):
                continue
            checked += 1
            used = {n.id for n in ast.walk(fn) if isinstance(n, ast.Name)}
            bad = sorted(used & (names | modules))
            if bad:
                offenders.append(f"{path.relative_to(ROOT)}:{fn.name} calls {bad}")
    assert checked > 50  # the check reads the kernel modules
    assert not offenders, offenders


def test_entry_is_the_one_signatures_compiled_code() -> None:
    """kernel_types.entry: the same result as the dispatcher; refused without exactly one
    explicit signature (the entry point would be ambiguous)."""
    import numpy as np
    import pytest
    from numba import njit

    from sara_app.kernel_types import RO1, W1, entry, types

    @njit(types.void(RO1, W1))
    def double(a, out):  # type: ignore[no-untyped-def]
        for i in range(a.shape[0]):
            out[i] = 2.0 * a[i]

    a, out = np.arange(4.0), np.zeros(4)
    entry(double)(a, out)
    np.testing.assert_array_equal(out, 2.0 * a)

    @njit
    def lazy(x):  # type: ignore[no-untyped-def]
        return x

    with pytest.raises(TypeError, match="one explicit signature"):
        entry(lazy)
