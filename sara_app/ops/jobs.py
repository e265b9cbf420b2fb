"""Background jobs of the dashboard and the API: what-if runs and evidence reports.

A job is a separate Python process (:mod:`sara_app.processes.job_main`) at the lowest CPU priority,
so a long simulation never runs in the worker, never blocks the dashboard or the API, and yields the
CPU to the live cell. :class:`JobRunner` starts at most one job at a time (this is a small
machine beside a 250 Hz worker: a second request is refused, not queued), follows its progress
lines and keeps the results of the last jobs.
"""

from __future__ import annotations

import itertools
import json
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import weakref
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sara_app.errors import InputError, SaraError, UnknownNameError

KEEP = 20
"""Finished jobs kept (their files too); older ones are removed."""
MAX_DURATION_S = 60.0
"""The longest simulated run a job may ask for (s): a what-if keeps every frame of its edited
run in memory, so the bound is also the job's memory."""
MAX_EPISODES = 50
"""The most adversarial episodes per mode an evidence report may ask for."""


class JobBusyError(SaraError):
    """A job is running already."""


@dataclass
class Job:
    id: str
    kind: str
    state: str = "running"
    """``running``, ``done`` or ``failed``."""
    progress: float = 0.0
    what: str = "starting"
    error: str | None = None
    started_s: float = field(default_factory=time.time)
    finished_s: float | None = None
    folder: Path = Path()
    label: str = ""
    pid: int | None = None
    """The job's process (while it runs)."""

    @property
    def output(self) -> Path:
        return self.folder / ("out.html" if self.kind == "report" else "out.json")

    def result(self) -> Any:
        """The what-if comparison (dict) or the report's evidence (dict); None before done."""
        if self.state != "done":
            return None
        path = self.output if self.kind == "whatif" else self.output.with_suffix(".json")
        return json.loads(path.read_text())

    def summary(self) -> dict[str, Any]:
        return {
            "id": self.id, "kind": self.kind, "label": self.label, "state": self.state,
            "progress": self.progress, "what": self.what, "error": self.error,
            "started_s": self.started_s, "finished_s": self.finished_s,
        }  # fmt: skip


def check_limits(kind: str, data: dict[str, Any]) -> None:
    """:class:`InputError` unless ``data``'s duration (``duration_s`` of a what-if, of a
    report's ``settings``) is None or a number in ``(0, MAX_DURATION_S]`` and a report's
    ``episodes`` an integer in ``[0, MAX_EPISODES]``. Checked here, where every job starts: the
    API's query checks them too, but a dashboard's number field is bounded only in the browser
    (viser does not check a value a client sends against the field's min and max)."""
    settings = data.get("settings", {}) if kind == "report" else data
    if not isinstance(settings, dict):
        raise InputError(
            f"a {kind} job's settings are a {type(settings).__name__}; expected an object"
        )
    duration = settings.get("duration_s")
    if duration is not None and not (
        isinstance(duration, int | float) and not isinstance(duration, bool)
        and 0.0 < duration <= MAX_DURATION_S  # NaN fails this too
    ):  # fmt: skip
        raise InputError(
            f"duration_s = {str(duration)[:40]!r}; expected a number of seconds in "
            f"(0, {MAX_DURATION_S:g}] or none (the scenario's own)"
        )
    episodes = settings.get("episodes", 0) if kind == "report" else 0
    if not (isinstance(episodes, int) and not isinstance(episodes, bool)
            and 0 <= episodes <= MAX_EPISODES):  # fmt: skip
        raise InputError(
            f"episodes = {str(episodes)[:40]!r}; expected an integer in [0, {MAX_EPISODES}]"
        )


class JobRunner:
    def __init__(self) -> None:
        self._jobs: dict[str, Job] = {}
        self._lock = threading.Lock()
        self._ids = itertools.count(1)
        self._root: Path | None = None
        """The jobs' folder, made by the first job (an API that never runs one leaves none)."""
        self._procs: dict[str, subprocess.Popen[str]] = {}
        self._cleanup: weakref.finalize | None = None  # type: ignore[type-arg]
        """:meth:`close`'s work, done at the latest when the runner is collected or the
        process exits (an app that made its own runner is never closed by its caller)."""

    def start(self, kind: str, data: dict[str, Any], label: str = "") -> Job:
        """Start job ``kind`` (``whatif`` or ``report``) on ``data`` (see
        :mod:`sara_app.processes.job_main`); :class:`JobBusyError` while another one runs."""
        if kind not in ("whatif", "report"):
            raise UnknownNameError("job kind", kind, ("whatif", "report"))
        check_limits(kind, data)
        with self._lock:
            busy = [j for j in self._jobs.values() if j.state == "running"]
            if busy:
                raise JobBusyError(
                    f"job {busy[0].id} ({busy[0].kind}) is still running "
                    f"({100 * busy[0].progress:.0f} %); one job runs at a time"
                )
            job = Job(f"{kind}-{next(self._ids)}", kind, label=label)
            if self._root is None:
                self._root = Path(tempfile.mkdtemp(prefix="sara-jobs-"))
                self._cleanup = weakref.finalize(self, _remove_jobs, self._procs, self._root)
            job.folder = self._root / job.id
            job.folder.mkdir()
            self._jobs[job.id] = job
            self._forget_old()
        inp = job.folder / "in.json"
        inp.write_text(json.dumps(data))
        proc = subprocess.Popen(
            [sys.executable, "-m", "sara_app.processes.job_main", kind, str(inp), str(job.output)],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip
        job.pid = proc.pid
        self._procs[job.id] = proc
        threading.Thread(target=self._follow, args=(job, proc), daemon=True).start()
        return job

    def _follow(self, job: Job, proc: subprocess.Popen[str]) -> None:
        stream = proc.stderr
        lines: list[str] = []
        if stream is not None:
            for line in stream:
                try:
                    msg = json.loads(line)
                except ValueError:
                    lines.append(line.strip())
                    continue
                if isinstance(msg, dict) and "progress" in msg:
                    job.progress, job.what = float(msg["progress"]), str(msg.get("what", ""))
                elif isinstance(msg, dict) and "error" in msg:
                    job.error = str(msg["error"])
        rc = proc.wait()
        self._procs.pop(job.id, None)
        job.finished_s = time.time()
        if rc == 0 and job.output.exists():
            job.state, job.progress, job.what = "done", 1.0, "done"
        else:
            job.state = "failed"
            job.error = job.error or f"exit status {rc}: " + " | ".join(lines[-3:])[:500]

    def _forget_old(self) -> None:
        done = [j for j in self._jobs.values() if j.state != "running"]
        for j in sorted(done, key=lambda j: j.started_s)[: max(len(done) - KEEP, 0)]:
            shutil.rmtree(j.folder, ignore_errors=True)
            del self._jobs[j.id]

    def get(self, job_id: str) -> Job:
        with self._lock:
            job = self._jobs.get(job_id)
            if job is None:
                raise UnknownNameError("job", job_id, tuple(self._jobs))
            return job

    def list(self) -> list[dict[str, Any]]:
        with self._lock:
            return [j.summary() for j in self._jobs.values()]

    def wait(self, job_id: str, timeout_s: float) -> Job:
        """Block until the job has finished (tests, the CLI); :class:`InputError` on timeout."""
        t_end = time.monotonic() + timeout_s
        job = self.get(job_id)
        while job.state == "running":
            if time.monotonic() > t_end:
                raise InputError(f"job {job_id} still running after {timeout_s} s")
            time.sleep(0.1)
        return job

    def close(self) -> None:
        """Stop a running job and remove every job's files."""
        if self._cleanup is not None:
            self._cleanup()


def _remove_jobs(procs: dict[str, subprocess.Popen[str]], root: Path) -> None:
    """Stop the running jobs' processes and remove the jobs' folder ``root``."""
    for proc in list(procs.values()):
        proc.kill()
        proc.wait(timeout=10)
    shutil.rmtree(root, ignore_errors=True)
