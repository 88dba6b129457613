"""The evaluators' side: lease a job, heartbeat, upload its result; plus the queue views and operator actions.

Request and reply bodies of the first three are the shared models of :mod:`proxybench.contract`. They
(and submissions) do all their database work in one worker-thread hop, commit included (``run_write``).
"""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Path, Query, Request, Response
from sqlalchemy import select
from sqlalchemy.orm import Session, joinedload

from proxybench.contract import Heartbeat, HeartbeatReply, Lease, LeaseRequest, ResultUpload
from proxybench.server import clock
from proxybench.server.api.artifacts import uploaded_under
from proxybench.server.api.deps import DB, Caller, Conf, require, run_write
from proxybench.server.api.schemas import (
    MAX_ID,
    EvaluatorOut,
    HostErrorRecorded,
    JobDetail,
    JobOut,
    ResultRecorded,
)
from proxybench.server.benchmarks import benchmark_of
from proxybench.server.config import Settings
from proxybench.server.errors import ServiceError
from proxybench.server.models import JOB_STATUSES, ArtifactLink, BenchmarkVersion, Evaluator, Job, Submission, User
from proxybench.server.queue import finish, heartbeat, lease, retry
from proxybench.server.submissions import advance
from proxybench.server.views import can_see, evaluator_view, job_events, job_view, result_view

router = APIRouter(tags=["jobs"])
EvaluatorUser = Annotated[User, Depends(require("evaluator"))]
Superuser = Annotated[User, Depends(require())]
JobId = Annotated[int, Path(ge=1, le=MAX_ID)]


def _evaluator(session: Session, user: User, name: str, features: list[str] | None = None,
               version: str | None = None) -> Evaluator:
    """The caller's evaluator of that name (registered on first contact); marks it seen."""
    ev = session.scalar(select(Evaluator).where(Evaluator.user_id == user.id, Evaluator.name == name))
    now = clock.now()
    if ev is None:
        if features is None:
            raise ServiceError(404, f"no evaluator {name!r} for user {user.name!r}; lease a job first")
        ev = Evaluator(user_id=user.id, name=name, features=sorted(set(features)), version=version or "",
                       created_at=now, last_seen_at=now, jobs_done=0)
        session.add(ev)
        session.flush()
    if features is not None and ev.features != sorted(set(features)):
        ev.features = sorted(set(features))
    if version is not None and ev.version != version:
        ev.version = version
    ev.last_seen_at = now
    return ev


@router.post("/jobs/lease", response_model=Lease, responses={204: {"description": "no job for these features now"}})
async def lease_job(body: LeaseRequest, request: Request, settings: Conf, user: EvaluatorUser) -> Any:
    """Lease the oldest job this evaluator can run; 204 when there is none. Keep it with heartbeats."""
    return await run_write(request, lambda session: _lease_job(body, session, settings, user))


def _lease_job(body: LeaseRequest, session: Session, settings: Settings, user: User) -> Any:
    ev = _evaluator(session, user, body.evaluator, body.features, body.version)
    job = lease(session, ev, settings.lease_seconds)
    if job is None:
        return Response(status_code=204)
    sub = job.submission
    bench = job.benchmark
    spec = benchmark_of(bench)  # its wall-clock budget: the evaluator ends a job that runs past it
    return Lease(job_id=job.id, lease_id=job.lease_id or "", lease_seconds=settings.lease_seconds,
                 attempt=job.attempts, step=job.step, features=job.features,
                 submission={"id": sub.id, "label": sub.label, "agent": sub.agent_name,
                             "archive_sha256": sub.archive_sha256, "manifest": sub.manifest},
                 benchmark={"name": bench.name, "version": bench.version, "spec_yaml": bench.spec_yaml,
                            "test_seed": bench.test_seed, "simulated_seconds": spec.simulated_seconds,
                            "wall_time_factor": spec.wall_time_factor})


@router.post("/jobs/{job_id}/heartbeat", response_model=HeartbeatReply)
async def job_heartbeat(job_id: JobId, body: Heartbeat, request: Request, settings: Conf,
                        user: EvaluatorUser) -> HeartbeatReply:
    """Extend the lease; 409 means it was lost (stop and drop the work)."""

    def work(session: Session) -> HeartbeatReply:
        ev = _evaluator(session, user, body.evaluator)
        expires = heartbeat(session, job_id, body.lease_id, ev, settings.lease_seconds, body.progress)
        return HeartbeatReply(job_id=job_id, lease_expires_at=expires)

    return await run_write(request, work)


@router.post("/jobs/{job_id}/result", response_model=ResultRecorded | HostErrorRecorded,
             response_model_exclude_unset=True,
             responses={201: {"description": "stored"}, 202: {"description": "host-error: the job was queued again"}})
async def job_result(job_id: JobId, body: ResultUpload, request: Request, settings: Conf, response: Response,
                     user: EvaluatorUser) -> Any:
    """Record the job's outcome. Safe to retry: the same lease's upload is stored once (200 on a repeat)."""
    return await run_write(request, lambda session: _job_result(job_id, body, request, session, settings, response,
                                                                user))


def _job_result(job_id: int, body: ResultUpload, request: Request, session: Session, settings: Settings,
                response: Response, user: User) -> Any:
    with session.no_autoflush:  # the evaluator's row is written once, with the result (not before each query)
        return _record_result(job_id, body, request, session, settings, response, user)


def _record_result(job_id: int, body: ResultUpload, request: Request, session: Session, settings: Settings,
                   response: Response, user: User) -> Any:
    ev = _evaluator(session, user, body.evaluator)
    job = session.get(Job, job_id, options=[joinedload(Job.benchmark), joinedload(Job.submission)])
    if job is None:
        raise ServiceError(404, f"no job {job_id}")
    store = request.app.state.store
    own = uploaded_under(session, job_id, body.lease_id) if body.artifacts else set()
    for k, ref in enumerate(body.artifacts):
        if ref.sha256 not in own or not store.has(ref.sha256):
            raise ServiceError(422, f"artifacts.{k}: {ref.name!r} ({ref.sha256[:12]}…) was not uploaded under this "
                                    "lease; PUT it to /api/v1/artifacts/{sha256}?job_id=…&lease_id=… first (a "
                                    "result names only artifacts its own lease uploaded)")
    if body.status == "success":
        _check_scores(job, body)
    result, created = finish(session, job_id, body, ev)
    if result is None:
        response.status_code = 202
        return HostErrorRecorded(job_id=job_id, status="host-error",
                                 requeued=session.get(Job, job_id).status == "queued")
    if created:
        for ref in body.artifacts:
            session.add(ArtifactLink(sha256=ref.sha256, submission_id=result.submission_id, result_id=result.id,
                                     name=ref.name, hidden=ref.hidden))
        opened = advance(session, result.job, result, settings.max_attempts)
        response.status_code = 201
    else:
        opened = []
    session.flush()
    links = [ref.model_dump() for ref in body.artifacts] if created else None  # a new result: its links are these
    return {**result_view(session, result, True, links=links), "recorded": created,
            "opened_jobs": [j.id for j in opened]}


def _check_scores(job: Job, body: ResultUpload) -> None:
    """A success must carry every score the benchmark ranks by (else its leaderboard could not rank it)."""
    needed = [c.metric for c in benchmark_of(job.benchmark).criteria()]
    for field, scores in (("public_scores", body.public_scores), ("hidden_scores", body.hidden_scores)):
        if field == "hidden_scores" and job.benchmark.test_seed is None:
            continue
        missing = [m for m in needed if m not in scores]
        if missing:
            raise ServiceError(422, f"{field}: missing {', '.join(missing)} (the benchmark ranks by them)")


_JOB_COLUMNS = (Job.id, Job.submission_id, Job.step, BenchmarkVersion.name, BenchmarkVersion.version, Job.features,
                Job.status, Job.attempts, Job.max_attempts, Job.message, Evaluator.name, Job.lease_expires_at,
                Job.progress, Job.created_at, Job.started_at, Job.finished_at)
_JOB_FIELDS = ("id", "submission_id", "step", "benchmark", "benchmark_version", "features", "status", "attempts",
               "max_attempts", "message", "evaluator", "lease_expires_at", "progress", "created_at", "started_at",
               "finished_at")


def list_jobs(session: Session, user: User, status: str | None = None, limit: int = 200) -> list[dict[str, Any]]:
    """The queue, newest first, as :func:`job_view` shows jobs: one query, no ORM objects."""
    if status is not None and status not in JOB_STATUSES:
        raise ServiceError(422, f"status must be one of {', '.join(JOB_STATUSES)}, got {status!r}")
    q = (select(*_JOB_COLUMNS).join(BenchmarkVersion, Job.benchmark_id == BenchmarkVersion.id)
         .outerjoin(Evaluator, Job.evaluator_id == Evaluator.id).order_by(Job.id.desc()).limit(limit))
    if status:
        q = q.where(Job.status == status)
    if user.role == "developer":
        q = q.join(Submission, Job.submission_id == Submission.id).where(Submission.user_id == user.id)
    return [dict(zip(_JOB_FIELDS, row, strict=True)) for row in session.execute(q)]


@router.get("/jobs", response_model=list[JobOut])
async def get_jobs(session: DB, user: Caller, status: str | None = None,
                   limit: Annotated[int, Query(ge=1, le=1000)] = 200) -> list[dict[str, Any]]:
    """The queue, newest first (super-users and evaluators: every job; developers: their own). One indexed
    query, run on the event loop."""
    return list_jobs(session, user, status, limit)


@router.get("/jobs/{job_id}", response_model=JobDetail)
def get_job(job_id: JobId, session: DB, user: Caller) -> dict[str, Any]:
    job = session.get(Job, job_id)
    if job is None:
        raise ServiceError(404, f"no job {job_id}")
    if user.role == "developer" and not can_see(user, job.submission):
        raise ServiceError(403, f"job {job_id} belongs to another user's submission")
    return {**job_view(job), "events": job_events(session, job_id)}


@router.post("/jobs/{job_id}/retry", status_code=201, response_model=JobOut)
def retry_job(job_id: JobId, session: DB, settings: Conf, _: Superuser) -> dict[str, Any]:
    """Operator: re-run a job that ended without success (as a new job)."""
    job = session.get(Job, job_id)
    if job is None:
        raise ServiceError(404, f"no job {job_id}")
    return job_view(retry(session, job, settings.max_attempts))


@router.get("/evaluators", response_model=list[EvaluatorOut])
def list_evaluators(session: DB, settings: Conf, _: Caller) -> list[dict[str, Any]]:
    """Evaluators and their health (seen within one lease period, on the server's clock)."""
    now = clock.now()
    return [evaluator_view(e, now, settings.lease_seconds)
            for e in session.scalars(select(Evaluator).order_by(Evaluator.last_seen_at.desc()))]
