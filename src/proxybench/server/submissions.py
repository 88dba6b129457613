"""Submissions: a built-in agent or an agent package, entered on one benchmark or on a benchmark path.

Creating one checks the developer's daily limit, retires their older submission with the same label
(its unfinished jobs are aborted; its results stay), and queues a job for every first step. When a
step's job succeeds, :func:`advance` opens the steps whose edge conditions hold.
"""

from __future__ import annotations

import time
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session

from proxybench.protocol.package import AgentManifest
from proxybench.server.benchmarks import benchmark_of, latest
from proxybench.server.errors import ServiceError
from proxybench.server.models import BenchmarkPath, BenchmarkVersion, Job, Result, Submission, User
from proxybench.server.paths import PathSpec, Step
from proxybench.server.queue import abort_jobs, log_event

__all__ = ["advance", "create_submission", "path_spec"]

_DAY = 86_400.0


def path_spec(session: Session, name: str) -> PathSpec:
    row = session.scalar(select(BenchmarkPath).where(BenchmarkPath.name == name))
    if row is None:
        raise ServiceError(404, f"no benchmark path named {name!r}")
    return PathSpec.model_validate(row.spec)


def _check_limit(session: Session, user: User, default_limit: int) -> None:
    limit = user.daily_limit if user.daily_limit is not None else default_limit
    if user.role == "superuser" or limit == 0:
        return
    # the user's row locked (PostgreSQL; SQLite's writers take turns): concurrent submissions count one by one
    session.execute(select(User.id).where(User.id == user.id).with_for_update())
    since = time.time() - _DAY
    n = session.scalar(select(func.count()).select_from(Submission)
                       .where(Submission.user_id == user.id, Submission.created_at > since)) or 0
    if n >= limit:
        raise ServiceError(429, f"daily submission limit reached: {n} of {limit} in the last 24 h for {user.name!r}")


def _queue(session: Session, sub: Submission, step: Step, max_attempts: int,
           bench: BenchmarkVersion | None = None) -> Job:
    """Queue a step's job (on ``bench``, the step's newest benchmark version, when the caller has it).

    The job is linked through its relationships, so the submission's job list and the job's benchmark
    are known in memory (the reply shows them without loading them again)."""
    bench = bench if bench is not None else latest(session, step.benchmark)
    job = Job(submission=sub, benchmark=bench, step=step.id,
              features=sorted(set(step.features) | set(bench.features)), status="queued",
              max_attempts=max_attempts, created_at=time.time())
    session.add(job)
    session.flush()
    log_event(session, job, "created", None, f"step {step.id!r}: {bench.name} v{bench.version}")
    return job


def create_submission(session: Session, user: User, *, label: str, description: str = "",
                      agent_name: str | None = None, archive_sha256: str | None = None,
                      manifest: AgentManifest | None = None, benchmark: str | None = None,
                      path: str | None = None, daily_limit: int = 20, max_attempts: int = 3) -> Submission:
    """Validate and store a submission and queue its first jobs, all in the caller's transaction."""
    if (agent_name is None) == (archive_sha256 is None):
        raise ServiceError(422, "a submission names exactly one of 'agent' (built-in) or an agent archive")
    if (benchmark is None) == (path is None):
        raise ServiceError(422, "a submission names exactly one of 'benchmark' or 'path'")
    if not label or len(label) > 64:
        raise ServiceError(422, "field 'label': 1 to 64 characters")
    if agent_name is not None:
        from proxybench.agents.zoo import ZOO

        if agent_name not in ZOO:
            raise ServiceError(422, f"field 'agent': no built-in agent {agent_name!r} (known: {', '.join(ZOO)})")
    spec = path_spec(session, path) if path is not None else PathSpec(steps=[Step(id="main", benchmark=benchmark)])
    rows = {name: latest(session, name) for name in {step.benchmark for step in spec.steps}}  # 404 now, not later
    for step in spec.steps:
        bench = benchmark_of(rows[step.benchmark])
        if agent_name is not None and bench.camera_only and ZOO[agent_name].privileged:
            raise ServiceError(422, f"field 'agent': {agent_name!r} is privileged (reads the true lane pose); "
                                    f"benchmark {bench.name!r} admits camera-only agents")
    _check_limit(session, user, daily_limit)
    for old in session.scalars(select(Submission).where(Submission.user_id == user.id, Submission.label == label,
                                                        Submission.status == "active")):
        old.status = "retired"
        abort_jobs(session, old, f"retired by a newer submission with label {label!r}")
    sub = Submission(user_id=user.id, label=label, description=description, agent_name=agent_name,
                     archive_sha256=archive_sha256, manifest=manifest.model_dump() if manifest else None,
                     path_name=path, benchmark_name=benchmark, status="active", created_at=time.time(),
                     jobs=[])  # known empty: its jobs are listed from memory, not loaded
    session.add(sub)
    session.flush()
    for step in spec.roots():
        _queue(session, sub, step, max_attempts, rows[step.benchmark])
    return sub


def _baseline_scores(session: Session, label: str, benchmark_id: int) -> dict[str, Any] | None:
    row = session.scalar(select(Result).join(Submission, Result.submission_id == Submission.id)
                         .where(Submission.label == label, Submission.status == "active",
                                Result.benchmark_id == benchmark_id, Result.status == "success")
                         .order_by(Result.id.desc()).limit(1))
    return row.public_scores if row is not None else None


def advance(session: Session, job: Job, result: Result, max_attempts: int) -> list[Job]:
    """After a successful step, queue each next step whose edge condition holds (once per step)."""
    sub = job.submission
    if result.status != "success" or sub.path_name is None or sub.status != "active":
        return []
    spec = path_spec(session, sub.path_name)
    existing = {j.step for j in sub.jobs}
    opened = []
    for edge in spec.edges_from(job.step):
        if edge.target in existing:
            continue
        ok = True
        if edge.condition is not None:
            criteria = benchmark_of(job.benchmark).criteria()
            base = (_baseline_scores(session, edge.condition.better_than, job.benchmark_id)
                    if edge.condition.better_than else None)
            ok = edge.condition.holds(result.public_scores, base, criteria)
        if ok:
            opened.append(_queue(session, sub, spec.step(edge.target), max_attempts))
        else:
            log_event(session, job, "path-stopped", None, f"condition to {edge.target!r} not met")
    return opened
