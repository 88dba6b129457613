"""Plain-data views of stored rows, shared by the JSON API and the web pages.

Hidden (test) scores, reports and artifacts appear only when ``superuser`` is true: developers never
receive them, not even for their own submissions.
"""

from __future__ import annotations

from typing import Any

from sqlalchemy import select
from sqlalchemy.orm import Session

from proxybench.server.models import ArtifactLink, Evaluator, Job, JobEvent, Result, Submission, User

__all__ = ["can_see", "evaluator_view", "job_view", "result_view", "submission_view"]


def can_see(user: User, sub: Submission) -> bool:
    return user.role == "superuser" or sub.user_id == user.id


def result_view(session: Session, r: Result, superuser: bool,
                links: list[dict[str, Any]] | None = None) -> dict[str, Any]:
    """A result as the API shows it; ``links`` (name, sha256, hidden) when the caller has them already."""
    if links is None:
        links = [{"name": a.name, "sha256": a.sha256, "hidden": a.hidden}
                 for a in session.scalars(select(ArtifactLink).where(ArtifactLink.result_id == r.id))]
    out = {"id": r.id, "job_id": r.job_id, "status": r.status, "public_scores": r.public_scores,
           "public_report": r.public_report, "message": r.message, "created_at": r.created_at,
           "artifacts": [a for a in links if superuser or not a["hidden"]]}
    if superuser:
        out.update(hidden_scores=r.hidden_scores, hidden_report=r.hidden_report)
    return out


def job_view(j: Job) -> dict[str, Any]:
    return {"id": j.id, "submission_id": j.submission_id, "step": j.step, "benchmark": j.benchmark.name,
            "benchmark_version": j.benchmark.version, "features": j.features, "status": j.status,
            "attempts": j.attempts, "max_attempts": j.max_attempts, "message": j.message,
            "evaluator": j.evaluator.name if j.evaluator else None, "lease_expires_at": j.lease_expires_at,
            "progress": j.progress, "created_at": j.created_at, "started_at": j.started_at,
            "finished_at": j.finished_at}


def submission_view(session: Session, s: Submission, superuser: bool, *, details: bool = True,
                    owner: User | None = None, new: bool = False) -> dict[str, Any]:
    """A submission as the API shows it. ``owner``: its user when the caller has it (no query for the name);
    ``new``: created in this transaction, so it has no results yet (no query for them)."""
    out: dict[str, Any] = {
        "id": s.id, "label": s.label, "description": s.description,
        "user": owner.name if owner is not None and owner.id == s.user_id else s.user.name, "status": s.status,
        "agent": s.agent_name, "archive_sha256": s.archive_sha256, "manifest": s.manifest,
        "benchmark": s.benchmark_name, "path": s.path_name, "created_at": s.created_at,
        "jobs": [job_view(j) for j in s.jobs],
    }
    if details and new:
        out["results"] = []
    elif details:
        results = session.scalars(select(Result).where(Result.submission_id == s.id).order_by(Result.id)).all()
        out["results"] = [result_view(session, r, superuser) for r in results]
    return out


def evaluator_view(e: Evaluator, now: float, lease_seconds: float) -> dict[str, Any]:
    return {"name": e.name, "owner_id": e.user_id, "features": e.features, "version": e.version,
            "last_seen_at": e.last_seen_at, "jobs_done": e.jobs_done,
            "healthy": now - e.last_seen_at <= lease_seconds}


def job_events(session: Session, job_id: int) -> list[dict[str, Any]]:
    rows = session.scalars(select(JobEvent).where(JobEvent.job_id == job_id).order_by(JobEvent.id))
    return [{"at": e.at, "kind": e.kind, "evaluator_id": e.evaluator_id, "message": e.message} for e in rows]
