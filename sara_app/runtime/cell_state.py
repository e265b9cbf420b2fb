"""The state in force of a live cell, on disk: the scenario its worker runs after every
accepted edit, so that a restarted worker (or ``serve``) runs what the audit log says was
applied.

One JSON file per cell in a state folder (``serve`` uses ``<data dir>/cells``, see
:func:`sara_app.ops.audit.default_data_dir`): ``{"origin": <the scenario the cell
was started with>, "revision": <accepted edits>, "saved_utc": ..., "scenario": {...}}``,
replaced atomically (written to a temporary file, flushed to disk, renamed) before the worker
acknowledges the edit: an acknowledged edit is on disk. A worker restored when started again
with the same origin (a restart); started with another scenario it begins afresh (that is a new
decision, and the file then follows the new origin). An unreadable file is reported and ignored,
never half-used.
"""

from __future__ import annotations

import json
import logging
import os
import tempfile
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sara_app.bus import keys

log = logging.getLogger("sara_app.worker")


class CellState:
    """``load(origin)`` and ``save(origin, scenario, revision)`` for one cell's file."""

    def __init__(self, folder: str | Path, cell: str) -> None:
        self.path = Path(folder) / f"{keys.check_name('cell', cell)}.json"

    def load(self, origin: str) -> tuple[dict[str, Any], int] | None:
        """The saved scenario and revision when the file exists and belongs to ``origin``."""
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as e:
            log.error("cell state %s cannot be read (%s): starting from the scenario", self.path, e)
            return None
        if not isinstance(data, dict) or not isinstance(data.get("scenario"), dict):
            log.error("cell state %s is not a saved state: starting from the scenario", self.path)
            return None
        if data.get("origin") != origin:
            log.warning(
                "cell state %s belongs to scenario %r, not %r: starting afresh",
                self.path, data.get("origin"), origin,
            )  # fmt: skip
            return None
        return data["scenario"], int(data.get("revision", 0))

    def save(self, origin: str, scenario: dict[str, Any], revision: int) -> None:
        """Replace the file atomically (raises OSError when it cannot be written)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        body = {
            "origin": origin,
            "revision": revision,
            "saved_utc": datetime.now(UTC).isoformat(timespec="milliseconds"),
            "scenario": scenario,
        }
        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=f".{self.path.stem}.")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                json.dump(body, fh, indent=1)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
