"""The job queue: leases with heartbeats, bounded retries, and results recorded exactly once.

Every change of a job's state is one conditional ``UPDATE … WHERE <the state expected>`` checked by the
rows it changed (:func:`_change`): leasing (``WHERE status = 'queued'``), heartbeats, results and host
errors (``WHERE status = 'evaluating' AND lease_id = …``), the reaper (``… AND lease_expires_at < now``),
aborts. That is correct on SQLite and PostgreSQL alike: two evaluators racing for one job cannot both get
it, and a result racing its lease's expiry either ends the job or is refused (409), never stored for a job
that is then leased again. On PostgreSQL the candidate is
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

from sqlalchemy import case, insert, select, update
from sqlalchemy.orm import Session, joinedload

from proxybench.contract import REPORTABLE, ResultUpload
from proxybench.server import clock
from proxybench.server.errors import ServiceError
from proxybench.server.models import FINAL_STATUSES, BenchmarkVersion, Evaluator, Job, JobEvent, Result, Submission

__all__ = ["REPORTABLE", "abort_jobs", "bump_boards", "finish", "heartbeat", "install_board_bumps", "lease",
           "log_event", "requeue_expired", "retry"]


def log_event(session: Session, job: Job | int, kind: str, evaluator_id: int | None = None, message: str = "") -> None:
    """One line of the job's history (a plain INSERT: no object for the unit of work to track)."""
    job_id = job if isinstance(job, int) else job.id
    session.execute(insert(JobEvent).values(job_id=job_id, at=time.time(), kind=kind, evaluator_id=evaluator_id,
                                            message=message))


def _released(status: str, message: str = "", *, final: Any = None) -> dict[str, Any]:
    """Column values of a job leaving its lease (``final``: whether it ends here; a SQL condition may say)."""
    if final is None:
        final = status in FINAL_STATUSES
    if not isinstance(final, bool):  # a SQL condition: the row decides
        return {"status": status, "lease_id": None, "lease_expires_at": None, "message": message,
                "finished_at": case((final, time.time()), else_=None)}
    return {"status": status, "lease_id": None, "lease_expires_at": None, "message": message,
            "finished_at": time.time() if final else None}


def _change(session: Session, where: tuple[Any, ...], values: dict[str, Any]) -> list[int]:
    """The one way a job's state changes: ``UPDATE jobs … WHERE <its expected state>``; the ids it changed.

    Whoever changes a job names the state it expects (status, and the lease for a held job); a job that
    moved on meanwhile is not touched. On PostgreSQL a second writer waits for the first's row lock, then
    evaluates its WHERE again on the committed row (so a reaper that read a lease as lapsed no longer
    matches a job whose result was just stored); on SQLite writers take turns. Job objects this session
    loaded are expired, so nothing stale is shown or written back.
    """
    ids = list(session.scalars(update(Job).where(*where).values(**values).returning(Job.id)
                               .execution_options(synchronize_session=False)))
    if ids:
        changed = set(ids)
        for obj in list(session.identity_map.values()):
            if isinstance(obj, Job) and obj.id in changed:
                session.expire(obj)
    return ids


def _held(job_id: int, lease_id: str, evaluator: Evaluator) -> tuple[Any, ...]:
    """WHERE: the job is still evaluating under this lease, held by this evaluator."""
    return (Job.id == job_id, Job.status == "evaluating", Job.lease_id == lease_id, Job.evaluator_id == evaluator.id)


def _lost(session: Session, job_id: int, lease_id: str, evaluator: Evaluator) -> ServiceError:
    status = session.scalar(select(Job.status).where(Job.id == job_id))
    if status is None:
        return ServiceError(404, f"no job {job_id}")
    return ServiceError(409, f"job {job_id}: lease {lease_id[:8]}… is no longer held by {evaluator.name!r} "
                             f"(job is {status}); stop working on it")


def requeue_expired(session: Session, now: float | None = None) -> int:
    """Return lapsed leases to the queue (or give the job up after its last attempt). Returns how many.

    Each job changes only if it still holds the very lease that was seen lapsed: a result or heartbeat that
    got there first wins, and the job is left alone."""
    now = clock.now() if now is None else now
    lapsed = session.execute(select(Job.id, Job.lease_id, Job.evaluator_id, Job.attempts, Job.max_attempts)
                             .where(Job.status == "evaluating", Job.lease_expires_at < now)).all()
    n = 0
    for job_id, lease_id, who, attempts, max_attempts in lapsed:  # the usual case: none (one indexed query)
        if attempts >= max_attempts:
            status, why = "timeout", f"lease lapsed on attempt {attempts} of {max_attempts}"
        else:
            status, why = "queued", "lease lapsed (evaluator silent); back in the queue"
        if _change(session, (Job.id == job_id, Job.status == "evaluating", Job.lease_id == lease_id,
                             Job.lease_expires_at < now), _released(status, why)):
            log_event(session, job_id, "lease-lapsed", who, why)
            n += 1
    return n


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


def heartbeat(session: Session, job_id: int, lease_id: str, evaluator: Evaluator, lease_seconds: float,
              progress: dict[str, Any] | None = None) -> float:
    """Extend a held lease; returns when it now lapses. 409 when it was lost (lapsed and re-leased, or the job
    was aborted)."""
    now = clock.now()
    values: dict[str, Any] = {"lease_expires_at": now + lease_seconds}
    if progress is not None:
        values["progress"] = progress
    if not _change(session, _held(job_id, lease_id, evaluator), values):
        raise _lost(session, job_id, lease_id, evaluator)
    evaluator.last_seen_at = now
    return now + lease_seconds


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

    The job leaves its lease in one conditional UPDATE (:func:`_change`) before the result is inserted: if
    the lease lapsed and the reaper (or another evaluator) got there first, nothing is stored and the
    answer is 409, so a stored result always belongs to a job that ended with it. ``host-error`` stores no
    result: the job is queued again with this evaluator excluded (or given up after the last attempt).
    The upload's text was cleaned by :class:`ResultUpload` (no NUL bytes).
    """
    lease_id, status = upload.lease_id, upload.status
    if status not in REPORTABLE:
        raise ServiceError(422, f"field 'status': {status!r} is not one of {', '.join(REPORTABLE)}")
    existing = session.scalar(select(Result).where(Result.job_id == job_id))
    if existing is not None:
        if existing.lease_id == lease_id:
            return existing, False  # the same upload again (the first reply was lost): already recorded
        raise ServiceError(409, f"job {job_id} already has a result (from another lease)")
    held = _held(job_id, lease_id, evaluator)
    if status == "host-error":
        final = Job.attempts >= Job.max_attempts
        if not _change(session, held, {**_released("queued", upload.message, final=final),
                                       "status": case((final, "host-error"), else_="queued")}):
            raise _lost(session, job_id, lease_id, evaluator)
        # the row is ours until commit (PostgreSQL's row lock, SQLite's write lock): extend its exclusions
        excluded = session.scalar(select(Job.excluded).where(Job.id == job_id)) or []
        _change(session, (Job.id == job_id,), {"excluded": [*excluded, evaluator.id]})
        evaluator.last_seen_at = clock.now()
        log_event(session, job_id, "host-error", evaluator.id, upload.message)
        return None, False
    if not _change(session, held, _released(status, upload.message)):
        again = session.scalar(select(Result).where(Result.job_id == job_id))
        if again is not None and again.lease_id == lease_id:  # a concurrent retry of this upload got there first
            return again, False
        raise _lost(session, job_id, lease_id, evaluator)
    job = session.get(Job, job_id)
    assert job is not None
    result = Result(job_id=job_id, submission_id=job.submission_id, benchmark_id=job.benchmark_id,
                    lease_id=lease_id, evaluator_id=evaluator.id, status=status,
                    public_scores=upload.public_scores, hidden_scores=upload.hidden_scores,
                    public_report=upload.public_report, hidden_report=upload.hidden_report,
                    message=upload.message, created_at=time.time())
    session.add(result)
    evaluator.last_seen_at = clock.now()
    evaluator.jobs_done = Evaluator.jobs_done + 1  # in SQL: concurrent results of one evaluator all count
    session.flush()  # the job row is locked by our UPDATE: no second result can get here for this job
    log_event(session, job_id, status, evaluator.id, result.message[:500])
    if status == "success":
        bump_boards(session, [job.benchmark_id])
    return result, True


def abort_jobs(session: Session, submission: Submission, why: str) -> int:
    """Abort a submission's unfinished jobs (it was retired or withdrawn); its boards change."""
    boards = session.scalars(select(Result.benchmark_id).where(Result.submission_id == submission.id,
                                                               Result.status == "success")).all()
    bump_boards(session, set(boards))
    ids = _change(session, (Job.submission_id == submission.id, Job.status.in_(("queued", "evaluating"))),
                  _released("aborted", why))
    for job_id in sorted(ids):
        log_event(session, job_id, "aborted", None, why)
    return len(ids)


def retry(session: Session, job: Job, max_attempts: int) -> Job:
    """An operator re-runs a job that ended without success: a new job; the old one and its result stay."""
    status = session.scalar(select(Job.status).where(Job.id == job.id).with_for_update())  # one retry at a time
    if status not in ("error", "timeout", "host-error", "aborted", "failed"):
        raise ServiceError(409, f"job {job.id} is {status}; only jobs that ended in error, timeout, "
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
