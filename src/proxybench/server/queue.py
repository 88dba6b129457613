"""The job queue: leases with heartbeats, bounded retries, and results recorded exactly once.

Leasing is an optimistic compare-and-set (``UPDATE … WHERE status = 'queued'``), which is correct on
SQLite and PostgreSQL alike without table locks: two evaluators racing for one job cannot both get it.
A lease lapses ``lease_seconds`` after the last heartbeat; the next queue operation puts the job back
(or, after ``max_attempts`` leases, gives it up as ``timeout``).

Outcomes an evaluator reports, as AIDO's: ``success``; ``failed`` (the submission's fault);
``error`` (the evaluator's fault, final until an operator retries); ``host-error`` (the job goes back to
the queue and that evaluator is excluded from it); ``aborted``.
"""

from __future__ import annotations

import secrets
import time
from typing import Any

from sqlalchemy import select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from proxybench.server.errors import ServiceError
from proxybench.server.models import FINAL_STATUSES, Evaluator, Job, JobEvent, Result, Submission

__all__ = ["REPORTABLE", "abort_jobs", "finish", "heartbeat", "lease", "log_event", "requeue_expired", "retry"]

REPORTABLE = ("success", "failed", "error", "host-error", "aborted")


def log_event(session: Session, job: Job, kind: str, evaluator_id: int | None = None, message: str = "") -> None:
    session.add(JobEvent(job_id=job.id, at=time.time(), kind=kind, evaluator_id=evaluator_id, message=message))


def _release(job: Job, status: str, message: str = "") -> None:
    job.status = status
    job.lease_id = None
    job.lease_expires_at = None
    job.message = message
    if status in FINAL_STATUSES:
        job.finished_at = time.time()


def requeue_expired(session: Session, now: float | None = None) -> int:
    """Return lapsed leases to the queue (or give the job up after its last attempt). Returns how many."""
    now = time.time() if now is None else now
    lapsed = session.scalars(select(Job).where(Job.status == "evaluating", Job.lease_expires_at < now)).all()
    for job in lapsed:
        who = job.evaluator_id
        if job.attempts >= job.max_attempts:
            _release(job, "timeout", f"lease lapsed on attempt {job.attempts} of {job.max_attempts}")
        else:
            _release(job, "queued", "lease lapsed (evaluator silent); back in the queue")
        log_event(session, job, "lease-lapsed", who, job.message)
    return len(lapsed)


def lease(session: Session, evaluator: Evaluator, lease_seconds: float) -> Job | None:
    """The oldest queued job this evaluator can run (features offered ⊇ required, not excluded), leased."""
    requeue_expired(session)
    offered = set(evaluator.features)
    candidates = session.scalars(select(Job).where(Job.status == "queued").order_by(Job.id).limit(200)).all()
    for job in candidates:
        if not set(job.features) <= offered or evaluator.id in job.excluded:
            continue
        lease_id = secrets.token_hex(16)
        now = time.time()
        got = session.execute(
            update(Job).where(Job.id == job.id, Job.status == "queued")
            .values(status="evaluating", lease_id=lease_id, evaluator_id=evaluator.id, attempts=Job.attempts + 1,
                    lease_expires_at=now + lease_seconds, started_at=now, message="")
            .execution_options(synchronize_session=False)
        ).rowcount
        if got == 1:
            session.refresh(job)
            log_event(session, job, "leased", evaluator.id, f"attempt {job.attempts}")
            return job
    return None


def _held(session: Session, job_id: int, lease_id: str, evaluator: Evaluator) -> Job:
    job = session.get(Job, job_id)
    if job is None:
        raise ServiceError(404, f"no job {job_id}")
    if job.status != "evaluating" or job.lease_id != lease_id or job.evaluator_id != evaluator.id:
        raise ServiceError(409, f"job {job_id}: lease {lease_id[:8]}… is no longer held by {evaluator.name!r} "
                                f"(job is {job.status}); stop working on it")
    return job


def heartbeat(session: Session, job_id: int, lease_id: str, evaluator: Evaluator, lease_seconds: float,
              progress: dict[str, Any] | None = None) -> Job:
    """Extend a held lease; 409 when the lease was lost (lapsed and re-leased, or the job was aborted)."""
    job = _held(session, job_id, lease_id, evaluator)
    job.lease_expires_at = time.time() + lease_seconds
    if progress is not None:
        job.progress = progress
    evaluator.last_seen_at = time.time()
    return job


def finish(session: Session, job_id: int, lease_id: str, evaluator: Evaluator, status: str,
           payload: dict[str, Any]) -> tuple[Result | None, bool]:
    """Record the outcome of a held lease. Returns (result, created); idempotent for a retried upload.

    ``host-error`` stores no result: the job is queued again with this evaluator excluded (or given up
    after the last attempt).
    """
    if status not in REPORTABLE:
        raise ServiceError(422, f"field 'status': {status!r} is not one of {', '.join(REPORTABLE)}")
    existing = session.scalar(select(Result).where(Result.job_id == job_id))
    if existing is not None:
        if existing.lease_id == lease_id:
            return existing, False  # the same upload again (the first reply was lost): already recorded
        raise ServiceError(409, f"job {job_id} already has a result (from another lease)")
    job = _held(session, job_id, lease_id, evaluator)
    evaluator.last_seen_at = time.time()
    if status == "host-error":
        job.excluded = [*job.excluded, evaluator.id]
        final = job.attempts >= job.max_attempts
        _release(job, "host-error" if final else "queued", str(payload.get("message", "")))
        log_event(session, job, "host-error", evaluator.id, job.message)
        return None, False
    result = Result(job_id=job.id, submission_id=job.submission_id, benchmark_id=job.benchmark_id,
                    lease_id=lease_id, evaluator_id=evaluator.id, status=status,
                    public_scores=payload.get("public_scores") or {}, hidden_scores=payload.get("hidden_scores") or {},
                    public_report=payload.get("public_report") or {}, hidden_report=payload.get("hidden_report") or {},
                    message=str(payload.get("message", "")), created_at=time.time())
    session.add(result)
    try:
        session.flush()
    except IntegrityError:  # a concurrent retry of the same upload won the race
        session.rollback()
        again = session.scalar(select(Result).where(Result.job_id == job_id))
        if again is not None and again.lease_id == lease_id:
            return again, False
        raise ServiceError(409, f"job {job_id} already has a result") from None
    _release(job, status, result.message)
    evaluator.jobs_done += 1
    log_event(session, job, status, evaluator.id, result.message[:500])
    return result, True


def abort_jobs(session: Session, submission: Submission, why: str) -> int:
    """Abort a submission's unfinished jobs (it was retired or withdrawn)."""
    n = 0
    for job in submission.jobs:
        if job.status in ("queued", "evaluating"):
            _release(job, "aborted", why)
            log_event(session, job, "aborted", None, why)
            n += 1
    return n


def retry(session: Session, job: Job, max_attempts: int) -> Job:
    """An operator re-runs a job that ended without success: a new job; the old one and its result stay."""
    if job.status not in ("error", "timeout", "host-error", "aborted", "failed"):
        raise ServiceError(409, f"job {job.id} is {job.status}; only jobs that ended in error, timeout, "
                                "host-error, aborted or failed can be retried")
    again = session.scalar(select(JobEvent).where(JobEvent.job_id == job.id, JobEvent.kind == "retried").limit(1))
    if again is not None:  # a double click or a repeated request must not queue the job twice
        raise ServiceError(409, f"job {job.id} was already retried ({again.message}); retry that job instead")
    new = Job(submission_id=job.submission_id, benchmark_id=job.benchmark_id, step=job.step, features=job.features,
              status="queued", max_attempts=max_attempts, created_at=time.time())
    session.add(new)
    session.flush()
    log_event(session, job, "retried", None, f"re-run as job {new.id}")
    log_event(session, new, "created", None, f"operator retry of job {job.id}")
    return new
