"""The audit log of threshold edits: one SQLite row per requested change and its outcome.

``AuditLog(path=None)`` opens (and creates, with its folder) the database; the default path is
:func:`default_audit_path`: ``$SARA_APP_DATA/audit.sqlite`` when that variable is set, else
``$XDG_DATA_HOME/sara_app/audit.sqlite`` (``~/.local/share/sara_app/audit.sqlite``).

A row holds the time (UTC ISO 8601 and epoch seconds), the cell, the scenario, the entry
(region / contact / shape), the old value, the requested value (``new_energy_J``; NULL when it
was not a finite number, ``requested`` keeps its text), the source's value and key, whether the
request exceeded the source value, whether it was confirmed, who asked (free text), where from
(``via``: api, dashboard) and the outcome: ``applied``, ``refused`` (with the reason) or
``no_answer`` (the worker did not answer in time: it may or may not have applied the change).

The same file holds the operators' actions on people (``person_actions``, schema version 2):
the time, the cell, the person, the action (``retire``), who, why and the outcome; and every
request to a mutating API route (``api_requests``: method, path, HTTP status, client, user,
body size), refused ones included; and every scenario edit that loosens what the verdict
assumes (``assumption_changes``: the changes in words, whether confirmed, who, where from, the
outcome; :mod:`sara_app.ops.loosening`); and the operators' actions on the robot
(``robot_actions``, schema version 5: ``replan``, the joint positions confirmed, who, where
from, why, the outcome and the worker's answer); and what the cell worker itself answered
(``worker_answers``, schema version 6: every scenario edit, retirement and re-plan that reached
it, whoever sent it, with the user its message names, whether a loosening was confirmed, the
outcome, why, and the configuration checksum in force after it;
:mod:`sara_app.runtime.ledger`).

Schema version ``PRAGMA user_version`` (:data:`SCHEMA_VERSION`; a version 1 file gains the
person table when opened); a newer file is refused rather than misread. Concurrent writers
(the API's threads, the dashboard, other processes): WAL
journal, a busy timeout and one short transaction per row, on a connection per call.
"""

from __future__ import annotations

import json
import logging
import math
import os
import sqlite3
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, NamedTuple

from sara_app.errors import ParameterError, SaraError

log = logging.getLogger("sara_app.audit")
SCHEMA_VERSION = 6
"""1: threshold_changes; 2: + person_actions; 3: + api_requests; 4: + assumption_changes; 5: +
robot_actions; 6: + worker_answers. Every
statement of the schema is idempotent (IF NOT EXISTS), so an older file is upgraded by running
them all."""
ENV_VAR = "SARA_APP_DATA"
OUTCOMES = ("applied", "refused", "no_answer")
WORKER_REQUESTS = ("edit", "retire", "replan")
MAX_TEXT = 2000  # reasons longer than this are cut
MAX_USER = 200
MAX_LIMIT = 10_000

_SCHEMA = (
    """CREATE TABLE IF NOT EXISTS threshold_changes (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    time_utc TEXT NOT NULL,
    time_epoch_s REAL NOT NULL,
    cell TEXT NOT NULL,
    scenario TEXT NOT NULL,
    region TEXT NOT NULL,
    contact TEXT NOT NULL,
    shape TEXT NOT NULL,
    old_energy_J REAL,
    new_energy_J REAL,
    requested TEXT NOT NULL,
    source_energy_J REAL,
    source_key TEXT,
    exceeds_source INTEGER NOT NULL,
    confirmed INTEGER NOT NULL,
    user TEXT NOT NULL,
    via TEXT NOT NULL,
    outcome TEXT NOT NULL CHECK (outcome IN ('applied', 'refused', 'no_answer')),
    reason TEXT NOT NULL
)""",
    "CREATE INDEX IF NOT EXISTS threshold_changes_cell ON threshold_changes (cell, id)",
    """CREATE TABLE IF NOT EXISTS person_actions (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    time_utc TEXT NOT NULL,
    time_epoch_s REAL NOT NULL,
    cell TEXT NOT NULL,
    human_id TEXT NOT NULL,
    action TEXT NOT NULL CHECK (action IN ('retire')),
    user TEXT NOT NULL,
    reason TEXT NOT NULL,
    outcome TEXT NOT NULL CHECK (outcome IN ('applied', 'refused', 'no_answer')),
    detail TEXT NOT NULL
)""",
    """CREATE TABLE IF NOT EXISTS api_requests (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    time_utc TEXT NOT NULL,
    time_epoch_s REAL NOT NULL,
    method TEXT NOT NULL,
    path TEXT NOT NULL,
    status INTEGER NOT NULL,
    client TEXT NOT NULL,
    user TEXT NOT NULL,
    body_bytes INTEGER NOT NULL
)""",
    """CREATE TABLE IF NOT EXISTS assumption_changes (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    time_utc TEXT NOT NULL,
    time_epoch_s REAL NOT NULL,
    cell TEXT NOT NULL,
    scenario TEXT NOT NULL,
    user TEXT NOT NULL,
    via TEXT NOT NULL,
    changes TEXT NOT NULL,
    confirmed INTEGER NOT NULL,
    outcome TEXT NOT NULL CHECK (outcome IN ('applied', 'refused', 'no_answer')),
    reason TEXT NOT NULL
)""",
    """CREATE TABLE IF NOT EXISTS robot_actions (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    time_utc TEXT NOT NULL,
    time_epoch_s REAL NOT NULL,
    cell TEXT NOT NULL,
    action TEXT NOT NULL CHECK (action IN ('replan')),
    q_rad TEXT NOT NULL,
    user TEXT NOT NULL,
    via TEXT NOT NULL,
    reason TEXT NOT NULL,
    outcome TEXT NOT NULL CHECK (outcome IN ('applied', 'refused', 'no_answer')),
    detail TEXT NOT NULL
)""",
    """CREATE TABLE IF NOT EXISTS worker_answers (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    time_utc TEXT NOT NULL,
    time_epoch_s REAL NOT NULL,
    cell TEXT NOT NULL,
    request TEXT NOT NULL CHECK (request IN ('edit', 'retire', 'replan')),
    request_id TEXT NOT NULL,
    user TEXT NOT NULL,
    confirmed INTEGER NOT NULL,
    outcome TEXT NOT NULL CHECK (outcome IN ('applied', 'refused')),
    reason TEXT NOT NULL,
    checksum TEXT NOT NULL,
    lost_before INTEGER NOT NULL
)""",
    "CREATE INDEX IF NOT EXISTS worker_answers_cell ON worker_answers (cell, id)",
)
_WORKER_COLUMNS = (
    "id, time_utc, time_epoch_s, cell, request, request_id, user, confirmed, outcome, reason, "
    "checksum, lost_before"
)
_ROBOT_COLUMNS = (
    "id, time_utc, time_epoch_s, cell, action, q_rad, user, via, reason, outcome, detail"
)
_CHANGE_COLUMNS = (
    "id, time_utc, time_epoch_s, cell, scenario, user, via, changes, confirmed, outcome, reason"
)
_REQUEST_COLUMNS = "id, time_utc, time_epoch_s, method, path, status, client, user, body_bytes"
_PERSON_COLUMNS = (
    "id, time_utc, time_epoch_s, cell, human_id, action, user, reason, outcome, detail"
)
_COLUMNS = (
    "id, time_utc, time_epoch_s, cell, scenario, region, contact, shape, old_energy_J, "
    "new_energy_J, requested, source_energy_J, source_key, exceeds_source, confirmed, user, "
    "via, outcome, reason"
)


class WorkerAnswer(NamedTuple):
    """One request the cell worker answered (:mod:`sara_app.runtime.ledger`): ``request`` is
    ``edit``, ``retire`` or ``replan``; ``user`` the one its message names; ``outcome``
    ``applied`` or ``refused``; ``checksum`` the configuration in force after it."""

    time_epoch_s: float
    cell: str
    request: str
    request_id: str
    user: str
    confirmed: bool
    outcome: str
    reason: str
    checksum: str


class AuditError(SaraError):
    """The audit database cannot be opened, is of a newer schema, or a write failed."""


def default_data_dir() -> Path:
    """``$SARA_APP_DATA``, else ``$XDG_DATA_HOME/sara_app``, else ``~/.local/share/sara_app``."""
    env = os.environ.get(ENV_VAR)
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_DATA_HOME")
    root = Path(xdg).expanduser() if xdg else Path.home() / ".local" / "share"
    return root / "sara_app"


def default_audit_path() -> Path:
    return default_data_dir() / "audit.sqlite"


@dataclass(frozen=True)
class AuditEntry:
    """One row of the log (energies in J; None where unknown or not a finite number)."""

    id: int
    time_utc: str
    time_epoch_s: float
    cell: str
    scenario: str
    region: str
    contact: str
    shape: str
    old_energy_J: float | None
    new_energy_J: float | None
    requested: str
    source_energy_J: float | None
    source_key: str | None
    exceeds_source: bool
    confirmed: bool
    user: str
    via: str
    outcome: str
    reason: str

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _finite_or_none(x: object) -> float | None:
    if isinstance(x, bool) or not isinstance(x, int | float):
        return None
    return float(x) if math.isfinite(float(x)) else None


def _clean_user(user: object) -> str:
    text = str(user).strip() if user is not None else ""
    if len(text) > MAX_USER:
        raise ParameterError(
            f"user {text[:40]!r}... has {len(text)} characters; at most {MAX_USER}"
        )
    return text or "unknown"


class AuditLog:
    """The threshold-edit audit log in one SQLite file (see the module docstring)."""

    def __init__(
        self,
        path: str | Path | None = None,
        *,
        clock: Callable[[], float] = time.time,
        busy_timeout_s: float = 5.0,
    ) -> None:
        self.path = Path(path) if path is not None else default_audit_path()
        self.clock = clock
        self.busy_timeout_s = float(busy_timeout_s)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise AuditError(
                f"audit folder {str(self.path.parent)!r} cannot be created: {e}"
            ) from e
        self._create()
        self._restrict()

    def _restrict(self) -> None:
        """Owner-only access (sqlite creates the file 0644; who changed what is not everyone's
        to read; its -wal and -shm files take the same mode). A file this user cannot chmod
        (another owner's) stays as it is, with a warning."""
        names = (self.path.name, self.path.name + "-wal", self.path.name + "-shm")
        for f in (self.path.with_name(n) for n in names):
            try:
                if f.exists() and f.stat().st_mode & 0o077:
                    f.chmod(0o600)
            except OSError as e:
                log.warning("audit log %s: access not restricted: %s", f, e)

    @contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        try:
            con = sqlite3.connect(self.path, timeout=self.busy_timeout_s, isolation_level=None)
        except sqlite3.Error as e:
            raise AuditError(f"audit log {str(self.path)!r} cannot be opened: {e}") from e
        try:
            yield con
        except sqlite3.Error as e:
            raise AuditError(f"audit log {str(self.path)!r}: {e}") from e
        finally:
            con.close()

    def _create(self) -> None:
        with self._connect() as con:
            con.execute("PRAGMA journal_mode=WAL")
            con.execute("BEGIN IMMEDIATE")  # one creator at a time
            try:
                version = int(con.execute("PRAGMA user_version").fetchone()[0])
                if version > SCHEMA_VERSION:
                    raise AuditError(
                        f"audit log {str(self.path)!r} has schema version {version}; this "
                        f"program reads versions up to {SCHEMA_VERSION}"
                    )
                if version < SCHEMA_VERSION:
                    for statement in _SCHEMA:
                        con.execute(statement)
                    con.execute(f"PRAGMA user_version = {SCHEMA_VERSION}")
                con.execute("COMMIT")
            except BaseException:
                if con.in_transaction:
                    con.execute("ROLLBACK")
                raise

    @property
    def schema_version(self) -> int:
        with self._connect() as con:
            return int(con.execute("PRAGMA user_version").fetchone()[0])

    # -- writing -------------------------------------------------------------------------------
    def _stamped(self, outcome: str | None) -> tuple[str, float]:
        """The row's time (UTC ISO 8601, epoch s), once ``outcome`` is known to be valid."""
        if outcome is not None and outcome not in OUTCOMES:
            raise ParameterError(f"audit outcome {outcome!r}; valid: {', '.join(OUTCOMES)}")
        now = float(self.clock())
        return datetime.fromtimestamp(now, UTC).isoformat(timespec="microseconds"), now

    def _insert(self, table: str, columns: str, row: tuple[Any, ...]) -> tuple[Any, ...]:
        """Insert ``row`` (every column of ``columns`` but ``id``) into ``table`` in one short
        transaction; the stored row, ``id`` first."""
        names = columns.split(", ", 1)[1]
        with self._connect() as con:
            cur = con.execute(
                f"INSERT INTO {table} ({names}) VALUES ({', '.join('?' * len(row))})", row
            )
            return tuple(
                con.execute(f"SELECT {columns} FROM {table} WHERE id = ?", (cur.lastrowid,))
                .fetchone()
            )  # fmt: skip

    def _of_cell(self, table: str, columns: str, cell: str, limit: int) -> list[tuple[Any, ...]]:
        """``cell``'s rows of ``table``, newest first (at most ``limit``)."""
        _check_limit(limit)
        sql = f"SELECT {columns} FROM {table} WHERE cell = ? ORDER BY id DESC LIMIT ?"
        with self._connect() as con:
            return list(con.execute(sql, (cell, limit)).fetchall())

    def record(
        self,
        *,
        cell: str,
        scenario: str,
        entry: tuple[str, str, str],
        requested: object,
        outcome: str,
        reason: str = "",
        old_energy_J: float | None = None,
        source_energy_J: float | None = None,
        source_key: str | None = None,
        exceeds_source: bool = False,
        confirmed: bool = False,
        user: object = "unknown",
        via: str = "api",
    ) -> AuditEntry:
        """Append one row (one short transaction); the stored entry."""
        stamp, now = self._stamped(outcome)
        row = (
            stamp,
            now,
            str(cell)[:64],
            str(scenario)[:64],
            *(str(x)[:64] for x in entry),
            _finite_or_none(old_energy_J),
            _finite_or_none(requested),
            repr(requested)[:64] if not isinstance(requested, str) else requested[:64],
            _finite_or_none(source_energy_J),
            source_key,
            int(bool(exceeds_source)),
            int(bool(confirmed)),
            _clean_user(user),
            str(via)[:32],
            outcome,
            str(reason)[:MAX_TEXT],
        )
        return _entry(self._insert("threshold_changes", _COLUMNS, row))

    def record_person_action(
        self,
        *,
        cell: str,
        human_id: str,
        user: object,
        reason: str,
        outcome: str,
        detail: str = "",
        action: str = "retire",
    ) -> dict[str, Any]:
        """Append one operator action on a person (one short transaction); the stored row."""
        stamp, now = self._stamped(outcome)
        row = (stamp, now, str(cell)[:64], str(human_id)[:64], action, _clean_user(user),
               str(reason)[:MAX_TEXT], outcome, str(detail)[:MAX_TEXT])  # fmt: skip
        got = self._insert("person_actions", _PERSON_COLUMNS, row)
        return dict(zip(_PERSON_COLUMNS.split(", "), got, strict=True))

    def record_robot_action(
        self,
        *,
        cell: str,
        q_rad: list[float],
        user: object,
        reason: str,
        outcome: str,
        detail: str = "",
        action: str = "replan",
        via: str = "api",
    ) -> dict[str, Any]:
        """Append one operator action on the robot (``q_rad``: the joint positions the operator
        confirmed; ``via``: api, dashboard); the stored row, ``q_rad`` as a list."""
        stamp, now = self._stamped(outcome)
        q_text = json.dumps([_finite_or_none(x) for x in q_rad][:64])
        row = (stamp, now, str(cell)[:64], action, q_text, _clean_user(user), str(via)[:32],
               str(reason)[:MAX_TEXT], outcome, str(detail)[:MAX_TEXT])  # fmt: skip
        return _robot_row(self._insert("robot_actions", _ROBOT_COLUMNS, row))

    def robot_actions(self, cell: str, limit: int = 50) -> list[dict[str, Any]]:
        """``cell``'s operator actions on the robot, newest first (at most ``limit``)."""
        return [_robot_row(r) for r in self._of_cell("robot_actions", _ROBOT_COLUMNS, cell, limit)]

    def record_request(
        self, method: str, path: str, status: int, client: str, user: str, body_bytes: int
    ) -> None:
        """One request to a mutating API route, whatever its outcome (refused ones too)."""
        stamp, now = self._stamped(None)
        row = (stamp, now, method[:8], path[:300], int(status), client[:64], _clean_user(user),
               int(body_bytes))  # fmt: skip
        names = _REQUEST_COLUMNS.split(", ", 1)[1]
        with self._connect() as con:
            con.execute(f"INSERT INTO api_requests ({names}) VALUES (?, ?, ?, ?, ?, ?, ?, ?)", row)

    def record_assumption_change(
        self,
        *,
        cell: str,
        scenario: str,
        changes: list[str],
        confirmed: bool,
        outcome: str,
        user: object = "unknown",
        via: str = "api",
        reason: str = "",
    ) -> dict[str, Any]:
        """Append one scenario edit that loosens what the verdict assumes
        (:mod:`sara_app.ops.loosening`), confirmed or refused, and its outcome; the stored row
        (``changes`` as a list)."""
        stamp, now = self._stamped(outcome)
        text = "\n".join(str(c).replace("\n", " ") for c in changes)[: 4 * MAX_TEXT]
        row = (stamp, now, str(cell)[:64], str(scenario)[:64], _clean_user(user), str(via)[:32],
               text, int(bool(confirmed)), outcome, str(reason)[:MAX_TEXT])  # fmt: skip
        return _change_row(self._insert("assumption_changes", _CHANGE_COLUMNS, row))

    def assumption_changes(self, cell: str, limit: int = 50) -> list[dict[str, Any]]:
        """``cell``'s loosening edits (confirmed and refused), newest first."""
        rows = self._of_cell("assumption_changes", _CHANGE_COLUMNS, cell, limit)
        return [_change_row(r) for r in rows]

    def record_worker_answers(self, rows: list[WorkerAnswer], lost_before: int = 0) -> None:
        """Append the worker's answers ``rows`` in one transaction; ``lost_before``: answers
        the worker could not record since its previous write (stored on the first row)."""
        out = []
        for k, a in enumerate(rows):
            if a.outcome not in ("applied", "refused") or a.request not in WORKER_REQUESTS:
                raise ParameterError(
                    f"worker answer {a.request!r} {a.outcome!r}; valid: {WORKER_REQUESTS}, "
                    "applied or refused"
                )
            stamp = datetime.fromtimestamp(a.time_epoch_s, UTC).isoformat(timespec="microseconds")
            out.append((stamp, float(a.time_epoch_s), str(a.cell)[:64], a.request,
                        str(a.request_id)[:64], _clean_user(a.user), int(bool(a.confirmed)),
                        a.outcome, str(a.reason)[:MAX_TEXT], str(a.checksum)[:64],
                        int(lost_before) if k == 0 else 0))  # fmt: skip
        names = _WORKER_COLUMNS.split(", ", 1)[1]
        sql = f"INSERT INTO worker_answers ({names}) VALUES ({', '.join('?' * 11)})"
        with self._connect() as con:
            con.execute("BEGIN")
            con.executemany(sql, out)
            con.execute("COMMIT")

    def worker_answers(self, cell: str, limit: int = 50) -> list[dict[str, Any]]:
        """``cell``'s requests as its worker answered them, newest first (at most ``limit``)."""
        rows = self._of_cell("worker_answers", _WORKER_COLUMNS, cell, limit)
        out = [dict(zip(_WORKER_COLUMNS.split(", "), r, strict=True)) for r in rows]
        for d in out:
            d["confirmed"] = bool(d["confirmed"])
        return out

    def requests(self, limit: int = 50) -> list[dict[str, Any]]:
        """The API's mutating requests, newest first."""
        _check_limit(limit)
        sql = f"SELECT {_REQUEST_COLUMNS} FROM api_requests ORDER BY id DESC LIMIT ?"
        with self._connect() as con:
            rows = con.execute(sql, (limit,)).fetchall()
        return [dict(zip(_REQUEST_COLUMNS.split(", "), r, strict=True)) for r in rows]

    def person_actions(self, cell: str, limit: int = 50) -> list[dict[str, Any]]:
        """``cell``'s operator actions on people, newest first (at most ``limit``)."""
        rows = self._of_cell("person_actions", _PERSON_COLUMNS, cell, limit)
        return [dict(zip(_PERSON_COLUMNS.split(", "), r, strict=True)) for r in rows]

    def entries(self, cell: str | None = None, limit: int = 50) -> list[AuditEntry]:
        """Newest first; only ``cell``'s rows when given; at most ``limit`` (1..10000)."""
        _check_limit(limit)
        sql = f"SELECT {_COLUMNS} FROM threshold_changes"
        args: tuple[Any, ...] = ()
        if cell is not None:
            sql += " WHERE cell = ?"
            args = (cell,)
        sql += " ORDER BY id DESC LIMIT ?"
        with self._connect() as con:
            rows = con.execute(sql, (*args, limit)).fetchall()
        return [_entry(r) for r in rows]


def _check_limit(limit: object) -> None:
    if isinstance(limit, bool) or not isinstance(limit, int) or not 1 <= limit <= MAX_LIMIT:
        raise ParameterError(f"audit limit {limit!r}; expected an integer in 1..{MAX_LIMIT}")


def _robot_row(row: tuple[Any, ...]) -> dict[str, Any]:
    out = dict(zip(_ROBOT_COLUMNS.split(", "), row, strict=True))
    out["q_rad"] = json.loads(out["q_rad"])
    return out


def _change_row(row: tuple[Any, ...]) -> dict[str, Any]:
    d = dict(zip(_CHANGE_COLUMNS.split(", "), row, strict=True))
    d["changes"] = d["changes"].split("\n") if d["changes"] else []
    d["confirmed"] = bool(d["confirmed"])
    return d


def _entry(row: tuple[Any, ...]) -> AuditEntry:
    d = dict(zip(_COLUMNS.split(", "), row, strict=True))
    d["exceeds_source"] = bool(d["exceeds_source"])
    d["confirmed"] = bool(d["confirmed"])
    return AuditEntry(**d)
