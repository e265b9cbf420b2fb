"""The numba types of every compiled kernel's signature, in one place.

Names: ``F8`` float64, ``I8`` int64, ``I1`` int8, ``B1`` boolean, ``IP`` intp; arrays of float64
``RO<d>`` (read-only, any layout, ``d`` dimensions), ``W<d>`` (writable), ``ROC<d>`` / ``WC<d>``
(C-contiguous); of int64 ``ROI<d>`` / ``WI<d>`` (``ROCI2`` C-contiguous); of int8 ``ROI8_<d>``
/ ``WI8_<d>``; of booleans ``ROB<d>`` / ``WB<d>``. ``RO`` and ``W`` map a dimension to the float
arrays. Signatures are explicit so that a kernel compiles (or loads from numba's cache) at
import, never in a control cycle.

Caching, one rule. Numba's cache checks only a function's own source file, so a cached function
whose compiled code includes a kernel of ANOTHER file would keep running that kernel's old code
after it changes. Therefore a cached kernel that calls kernels of other files carries their
source digests in its closure (it is built by a ``_make_*`` function; the digests are part of
its cache key), and a helper that calls kernels of other files is not cached on its own
(plain ``@njit``: it is compiled into its callers). ``tests/test_kernel_types.py`` checks every
kernel module for it.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
from numba import types

F8, I8, I1, B1, IP = types.float64, types.int64, types.int8, types.boolean, types.intp

_D = (1, 2, 3, 4, 5)
RO = {d: types.Array(F8, d, "A", readonly=True) for d in _D}
W = {d: types.Array(F8, d, "A") for d in _D}
RO1, RO2, RO3, RO4, RO5 = (RO[d] for d in _D)
W1, W2, W3, W4, W5 = (W[d] for d in _D)
ROC2 = types.Array(F8, 2, "C", readonly=True)
WC1, WC2, WC3 = (types.Array(F8, d, "C") for d in (1, 2, 3))
ROI1, ROI2, ROI3 = (types.Array(I8, d, "A", readonly=True) for d in (1, 2, 3))
ROCI2 = types.Array(I8, 2, "C", readonly=True)
WI1, WI2, WI3 = (types.Array(I8, d, "A") for d in (1, 2, 3))
ROI8_3 = types.Array(I1, 3, "A", readonly=True)
WI8_3 = types.Array(I1, 3, "A")
ROB1, ROB2, ROB3 = (types.Array(B1, d, "A", readonly=True) for d in (1, 2, 3))
WB1, WB2, WB3 = (types.Array(B1, d, "A") for d in (1, 2, 3))


def entry(kernel: Any) -> Callable[..., Any]:
    """The compiled code of ``kernel``'s one explicit signature, called without numba's
    dispatcher. The dispatcher types every argument at each call to pick an overload (about
    20-50 ns per argument: a fifth of a one-person reach set's cost). Contract: the caller passes
    exactly the signature's types, float64 / int64 arrays of the stated dimension counts and
    Python or numpy scalars; numba's unboxing checks only an array's item size, so a wrong
    dimension count, or an int64 array where float64 is declared, is read as the declared
    type. Use it only behind a wrapper that has checked its arguments' dtypes and shapes (e.g.
    :meth:`sara_app.human.reach.HumanReach.pos`)."""
    if len(kernel.signatures) != 1:
        raise TypeError(f"{kernel!r} must have exactly one explicit signature")
    return kernel.overloads[kernel.signatures[0]].entry_point  # type: ignore[no-any-return]


FLOAT64 = np.dtype(np.float64)


def as_f8(a: Any) -> np.ndarray:
    """``a`` as a float64 array: the same object when it is one already (``np.asarray`` with a
    dtype costs a few hundred ns even then; the compiled kernels' wrappers call this per input)."""
    return a if type(a) is np.ndarray and a.dtype is FLOAT64 else np.asarray(a, np.float64)


def source_digest(module: ModuleType) -> str:
    """SHA-256 (hex) of a module's source file: the closure variable that ties a cached kernel
    to the kernels of another file it calls (the caching rule above), and the key of other
    caches that must follow a file's code (the robot's fitted capsules)."""
    return hashlib.sha256(Path(str(module.__file__)).read_bytes()).hexdigest()
