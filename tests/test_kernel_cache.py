"""Every cached compiled kernel loads from numba's cache in a new process: a kernel's closure
holds only plain values. Numba pickles a closure's values into the cache key, and a compiled
function pickles with an identity new in every process, so a kernel that held one as a closure
variable missed the cache at every start (``classify_set``: 1.5 s of compiling in every worker,
simulator and test process, and a cache file more per start)."""

from __future__ import annotations

import importlib
import pkgutil

from numba.core.caching import FunctionCache
from numba.core.registry import CPUDispatcher

import sara_app

PLAIN = (str, bytes, int, float, bool)


def _kernels() -> list[tuple[str, CPUDispatcher]]:
    out = []
    for mod in pkgutil.walk_packages(sara_app.__path__, "sara_app."):
        if not mod.name.endswith("_kernels"):
            continue
        module = importlib.import_module(mod.name)
        for name, f in vars(module).items():
            if isinstance(f, CPUDispatcher) and isinstance(f._cache, FunctionCache):
                out.append((f"{mod.name}.{name}", f))
    return out


def test_cached_kernels_close_over_plain_values_only() -> None:
    kernels = _kernels()
    assert len(kernels) > 20  # the walk found the package's kernels
    closures = [(n, f) for n, f in kernels if f.py_func.__closure__]
    assert closures  # the source-digest closures are among them
    bad = [
        (n, var, type(cell.cell_contents).__name__)
        for n, f in closures
        for var, cell in zip(f.py_func.__code__.co_freevars, f.py_func.__closure__)
        if not isinstance(cell.cell_contents, PLAIN)
    ]
    assert not bad, f"closure variables that change numba's cache key in every process: {bad}"
