"""The configuration checksum of a cell: what an auditor compares between an evidence report
and the running worker.

It is the SHA-256 of one canonical JSON document holding everything that decides what the
cell does: the scenario as validated (robot, limits, task, environment, people, shield settings
with the threshold edits), the human parameter set and the threshold set it names, resolved to
their contents (a shipped set edited on disk changes the checksum although its name did not),
and the code: the package version and a digest of every source and data file of ``sara_app``
(not caches). Any edit of any of them changes the checksum; the same configuration on another
machine gives the same one.
"""

from __future__ import annotations

import hashlib
import json
from functools import lru_cache
from pathlib import Path
from typing import Any

from sara_app import __version__
from sara_app.scenario import Scenario

PACKAGE_DIR = Path(__file__).resolve().parents[1]
"""The package root (``sara_app/``): every file under it is code the checksum covers."""
SKIPPED_SUFFIXES = (".pyc", ".nbi", ".nbc")
"""Caches (bytecode, numba's compiled kernels) are not code: they differ between machines."""


@lru_cache(maxsize=1)
def code_digest() -> str:
    """SHA-256 over the relative path and bytes of every file of the package, in path order
    (computed once per process: the code does not change under a running process)."""
    h = hashlib.sha256()
    files = sorted(
        p
        for p in PACKAGE_DIR.rglob("*")
        if p.is_file() and "__pycache__" not in p.parts and p.suffix not in SKIPPED_SUFFIXES
    )
    for p in files:
        h.update(p.relative_to(PACKAGE_DIR).as_posix().encode())
        h.update(b"\0")
        h.update(p.read_bytes())
        h.update(b"\0")
    return h.hexdigest()


def configuration(sc: Scenario) -> dict[str, Any]:
    """The document the checksum is taken of (JSON-ready)."""
    return {
        "scenario": sc.model_dump(mode="json"),
        "human_params": sc.param_set().model_dump(mode="json"),
        "thresholds": sc.shield.pfl.source_set().model_dump(mode="json"),
        "code": {"version": __version__, "sha256": code_digest()},
    }


def config_checksum(sc: Scenario) -> str:
    """SHA-256 (hex) of :func:`configuration` in canonical JSON (sorted keys, no spaces)."""
    doc = json.dumps(configuration(sc), sort_keys=True, separators=(",", ":"), allow_nan=False)
    return hashlib.sha256(doc.encode()).hexdigest()
