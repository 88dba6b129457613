"""The job queue: leases with heartbeats, bounded retries, and results recorded exactly once.

Leasing is a compare-and-set (``UPDATE … WHERE status = 'queued'``), which is correct on SQLite and
PostgreSQL alike: two evaluators racing for one job cannot both get it. On PostgreSQL the candidate is
first locked with ``FOR UPDATE SKIP LOCKED``, so racing evaluators take different jobs instead of queueing
behind one row lock. A lease lapses ``lease_seconds`` after the last heartbeat, on the server's monotonic
clock (:mod:`.clock`: a wall-clock step cannot end leases); the next queue operation or the reaper puts
the job back (or, after ``max_attempts`` leases, gives it up as ``timeout``).

Outcomes an evaluator reports, as AIDO's: ``success``; ``failed`` (the submission's fault);
``error`` (the evaluator's fault, final until an operator retries); ``host-error`` (the job goes back to
the queue and that evaluator is excluded from it); ``aborted``.
"""

from __future__ import annotations

import secrets
import time
from typing import Any

from sqlalchemy import insert, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, joinedload

from proxybench.contract import REPORTABLE, ResultUpload
from proxybench.server import clock
from proxybench.server.errors import ServiceError
from proxybench.server.models import FINAL_STATUSES, BenchmarkVersion, Evaluator, Job, JobEvent, Result, Submission

__all__ = ["REPORTABLE", "abort_jobs", "bump_boards", "finish", "heartbeat", "install_board_bumps", "lease",
           "log_event", "requeue_expired", "retry"]


def log_event(session: Session, job: Job, kind: str, evaluator_id: int | None = None, message: str = "") -> None:
    """One line of the job's history (a plain INSERT: no object for the unit of work to track)."""
    session.execute(insert(JobEvent).values(job_id=job.id, at=time.time(), kind=kind, evaluator_id=evaluator_id,
                                            message=message))


def _release(job: Job, status: str, message: str = "") -> None:
    job.status = status
    job.lease_id = None
    job.lease_expires_at = None
    job.message = message
    if status in FINAL_STATUSES:
        job.finished_at = time.time()


def requeue_expired(session: Session, now: float | None = None) -> int:
    """Return lapsed leases to the queue (or give the job up after its last attempt). Returns how many."""
    now = clock.now() if now is None else now
    ids = session.scalars(select(Job.id).where(Job.status == "evaluating", Job.lease_expires_at < now)).all()
    if not ids:  # the usual case: one cheap indexed query, no objects
        return 0
    lapsed = session.scalars(select(Job).where(Job.id.in_(ids), Job.status == "evaluating",
                                               Job.lease_expires_at < now)).all()
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
    rows = session.execute(select(Job.id, Job.features, Job.excluded).where(Job.status == "queued")
                           .order_by(Job.id).limit(200)).all()
    eligible = [jid for jid, features, excluded in rows
                if set(features) <= offered and evaluator.id not in (excluded or [])]
    skip_locked = session.get_bind().dialect.name == "postgresql"
    while eligible:
        if skip_locked:  # take one nobody else is taking right now, without waiting for their row locks
            jid = session.scalar(select(Job.id).where(Job.id.in_(eligible[:50]), Job.status == "queued")
                                 .order_by(Job.id).limit(1).with_for_update(skip_locked=True))
            if jid is None:
                if len(eligible) <= 50:
                    return None
                eligible = eligible[50:]
                continue
        else:
            jid = eligible[0]
        eligible.remove(jid)
        lease_id = secrets.token_hex(16)
        now = clock.now()
        got = session.execute(
            update(Job).where(Job.id == jid, Job.status == "queued")
            .values(status="evaluating", lease_id=lease_id, evaluator_id=evaluator.id, attempts=Job.attempts + 1,
                    lease_expires_at=now + lease_seconds, started_at=time.time(), message="")
            .execution_options(synchronize_session=False)
        ).rowcount
        if got == 1:
            job = session.get(Job, jid, populate_existing=True,
                              options=[joinedload(Job.submission), joinedload(Job.benchmark)])
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
    job.lease_expires_at = clock.now() + lease_seconds
    if progress is not None:
        job.progress = progress
    evaluator.last_seen_at = clock.now()
    return job


def bump_boards(session: Session, benchmark_ids: set[int] | list[int]) -> None:
    """Mark these benchmark versions' leaderboards changed: their ``board_version`` is bumped just before
    this transaction commits (:func:`install_board_bumps`; a hot row, locked as briefly as possible), and
    the ids are noted in ``session.info["changed_boards"]`` so the request has the boards rebuilt after."""
    session.info.setdefault("changed_boards", set()).update(benchmark_ids)


def _bump_before_commit(session: Session) -> None:
    changed = session.info.pop("changed_boards", set())
    for bid in sorted(changed):  # a fixed order: no crosswise locks
        session.execute(update(BenchmarkVersion).where(BenchmarkVersion.id == bid)
                        .values(board_version=BenchmarkVersion.board_version + 1)
                        .execution_options(synchronize_session=False))
    session.info.setdefault("bumped_boards", set()).update(changed)


def _forget_on_rollback(session: Session) -> None:
    session.info.pop("changed_boards", None)
    session.info.pop("bumped_boards", None)


def install_board_bumps(factory) -> None:
    """Have every session of ``factory`` bump the board versions it changed as the last thing before commit
    (then listed in ``session.info["bumped_boards"]``), and forget them on a rollback."""
    from sqlalchemy import event

    event.listen(factory, "before_commit", _bump_before_commit)
    event.listen(factory, "after_soft_rollback", lambda session, _tx: _forget_on_rollback(session))


def finish(session: Session, job_id: int, upload: ResultUpload, evaluator: Evaluator) -> tuple[Result | None, bool]:
    """Record the outcome of a held lease. Returns (result, created); idempotent for a retried upload.

    ``host-error`` stores no result: the job is queued again with this evaluator excluded (or given up
    after the last attempt). The upload's text was cleaned by :class:`ResultUpload` (no NUL bytes).
    """
    lease_id, status = upload.lease_id, upload.status
    if status not in REPORTABLE:
        raise ServiceError(422, f"field 'status': {status!r} is not one of {', '.join(REPORTABLE)}")
    existing = session.scalar(select(Result).where(Result.job_id == job_id))
    if existing is not None:
        if existing.lease_id == lease_id:
            return existing, False  # the same upload again (the first reply was lost): already recorded
        raise ServiceError(409, f"job {job_id} already has a result (from another lease)")
    job = _held(session, job_id, lease_id, evaluator)
    evaluator.last_seen_at = clock.now()
    if status == "host-error":
        job.excluded = [*job.excluded, evaluator.id]
        final = job.attempts >= job.max_attempts
        _release(job, "host-error" if final else "queued", upload.message)
        log_event(session, job, "host-error", evaluator.id, job.message)
        return None, False
    result = Result(job_id=job.id, submission_id=job.submission_id, benchmark_id=job.benchmark_id,
                    lease_id=lease_id, evaluator_id=evaluator.id, status=status,
                    public_scores=upload.public_scores, hidden_scores=upload.hidden_scores,
                    public_report=upload.public_report, hidden_report=upload.hidden_report,
                    message=upload.message, created_at=time.time())
    session.add(result)
    _release(job, status, result.message)  # before the flush: one UPDATE per row (a failed flush rolls back)
    evaluator.jobs_done += 1
    try:
        session.flush()
    except IntegrityError:  # a concurrent retry of the same upload won the race
        session.rollback()
        again = session.scalar(select(Result).where(Result.job_id == job_id))
        if again is not None and again.lease_id == lease_id:
            return again, False
        raise ServiceError(409, f"job {job_id} already has a result") from None
    log_event(session, job, status, evaluator.id, result.message[:500])
    if status == "success":
        bump_boards(session, [job.benchmark_id])
    return result, True


def abort_jobs(session: Session, submission: Submission, why: str) -> int:
    """Abort a submission's unfinished jobs (it was retired or withdrawn); its boards change."""
    boards = session.scalars(select(Result.benchmark_id).where(Result.submission_id == submission.id,
                                                               Result.status == "success")).all()
    bump_boards(session, set(boards))
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
