"""Stand-ins for the REST service's tests: a worker that answers without a bus and a job runner
that starts no process."""

from __future__ import annotations

from typing import Any

from test_api_thresholds import StandInRegistry

from sara_app.api.registry import ParamsAnswer
from sara_app.ops.jobs import Job, JobRunner

KNOWN_PERSON = "h1"


class AnsweringRegistry(StandInRegistry):
    """The stand-in worker also answers retire requests: it knows person ``h1`` only;
    ``retired_by``: the user each request named."""

    def __init__(self) -> None:
        super().__init__()
        self.retired_by: list[str] = []

    def request_retire(
        self, cell: str, human_id: str, user: str, reason: str, timeout_s: float = 3.0
    ) -> ParamsAnswer:
        self.retired_by.append(user)
        known = human_id == KNOWN_PERSON
        return ParamsAnswer("retire", known, "" if known else f"person {human_id!r} not known")


class InertJobs(JobRunner):
    """Lists a job instead of starting its process (a what-if run takes minutes here): the job
    shows as failed, with that reason (no folder is made: the runner makes one for a job's
    files when a job starts)."""

    def start(self, kind: str, data: dict[str, Any], label: str = "") -> Job:
        with self._lock:
            job = Job(f"{kind}-{next(self._ids)}", kind, state="failed", label=label)
            job.error = "not run: the test's stand-in job runner"
            self._jobs[job.id] = job
        return job
