"""A worker's job for tests of the evaluator's worker (:class:`proxybench.evaluator.run._Job`): a typed lease
with the fields a test does not care about filled in."""

from __future__ import annotations

from typing import Any

from proxybench.contract import Lease, LeasedBenchmark, LeasedSubmission
from proxybench.evaluator.job import EvaluatorInfo, WorkerJob
from proxybench.evaluator.sandbox import Isolation

__all__ = ["worker_job"]


def worker_job(isolation: Isolation | None = None, *, agent: str | None = None, archive_sha256: str | None = None,
               **fields: Any) -> WorkerJob:
    """A job of submission 1 (``agent`` or the archive ``archive_sha256``) on an empty benchmark; ``fields``:
    the rest of :class:`WorkerJob` (``robot_options``, ``limits``, ...)."""
    lease = Lease(job_id=1, lease_id="ab", lease_seconds=60.0,
                  submission=LeasedSubmission(id=1, label="test", agent=agent, archive_sha256=archive_sha256),
                  benchmark=LeasedBenchmark(name="test", version=1, spec_yaml="{}"))
    return WorkerJob(lease=lease, evaluator=EvaluatorInfo(name="test"),
                     isolation=isolation or Isolation("unavailable", "test", problem="not needed here"), **fields)
