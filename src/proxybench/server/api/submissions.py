"""Submissions: built-in agents (JSON) or agent packages (multipart upload); listing, details, retiring."""

from __future__ import annotations

import time
from typing import Annotated, Any

from fastapi import APIRouter, Depends, Form, Request, UploadFile
from sqlalchemy import select

from proxybench.agents.package import PackageError, check_archive
from proxybench.server.api.deps import DB, Caller, Conf, require
from proxybench.server.api.schemas import SubmissionCreate
from proxybench.server.artifacts import TooLarge
from proxybench.server.errors import ServiceError
from proxybench.server.models import ArtifactLink, Submission, User
from proxybench.server.queue import abort_jobs
from proxybench.server.submissions import create_submission
from proxybench.server.views import can_see, submission_view

router = APIRouter(tags=["submissions"])
Developer = Annotated[User, Depends(require("developer"))]


@router.post("/submissions", status_code=201)
def submit_builtin(body: SubmissionCreate, session: DB, settings: Conf, user: Developer) -> dict[str, Any]:
    """Submit a built-in agent to a benchmark or a benchmark path."""
    sub = create_submission(session, user, label=body.label, description=body.description, agent_name=body.agent,
                            benchmark=body.benchmark, path=body.path, daily_limit=settings.daily_submission_limit,
                            max_attempts=settings.max_attempts)
    return submission_view(session, sub, user.role == "superuser")


def _chunks(upload: UploadFile):
    while chunk := upload.file.read(1 << 20):
        yield chunk


@router.post("/submissions/upload", status_code=201)
def submit_archive(request: Request, session: DB, settings: Conf, user: Developer,
                   archive: UploadFile, label: Annotated[str, Form()], description: Annotated[str, Form()] = "",
                   benchmark: Annotated[str | None, Form()] = None,
                   path: Annotated[str | None, Form()] = None) -> dict[str, Any]:
    """Submit an agent package (zip or tar.gz with ``proxybench-agent.yaml``); checked before it is stored."""
    data = b"".join(_chunks(archive))
    if len(data) > settings.archive_max_bytes:
        raise ServiceError(413, f"archive is {len(data)} bytes; the limit is {settings.archive_max_bytes}")
    try:
        manifest = check_archive(data)
    except PackageError as exc:
        raise ServiceError(422, f"archive {archive.filename!r}: {exc}") from None
    store = request.app.state.store
    try:
        sha, size = store.write([data], settings.archive_max_bytes)
    except TooLarge as exc:
        raise ServiceError(413, str(exc)) from None
    store.record(session, sha, size, "application/octet-stream", user.id)
    sub = create_submission(session, user, label=label, description=description, archive_sha256=sha,
                            manifest=manifest, benchmark=benchmark, path=path,
                            daily_limit=settings.daily_submission_limit, max_attempts=settings.max_attempts)
    session.add(ArtifactLink(sha256=sha, submission_id=sub.id, name=archive.filename or "agent-archive"))
    return submission_view(session, sub, user.role == "superuser")


@router.get("/submissions")
def list_submissions(session: DB, user: Caller, mine: bool = False) -> list[dict[str, Any]]:
    """Your submissions (super-users: everyone's, unless ``mine``)."""
    q = select(Submission).order_by(Submission.id.desc())
    if user.role != "superuser" or mine:
        q = q.where(Submission.user_id == user.id)
    return [submission_view(session, s, user.role == "superuser", details=False) for s in session.scalars(q)]


def _own(session: DB, user: User, sid: int) -> Submission:
    sub = session.get(Submission, sid)
    if sub is None:
        raise ServiceError(404, f"no submission {sid}")
    if not can_see(user, sub):
        raise ServiceError(403, f"submission {sid} belongs to another user")
    return sub


@router.get("/submissions/{sid}")
def get_submission(sid: int, session: DB, user: Caller) -> dict[str, Any]:
    """A submission with its jobs and results (hidden scores only for super-users)."""
    return submission_view(session, _own(session, user, sid), user.role == "superuser")


@router.post("/submissions/{sid}/retire")
def retire(sid: int, session: DB, user: Caller) -> dict[str, Any]:
    """Withdraw a submission from the leaderboards; its unfinished jobs are aborted, its results kept."""
    sub = _own(session, user, sid)
    sub.status = "retired"
    n = abort_jobs(session, sub, f"retired by {user.name!r} at {time.strftime('%Y-%m-%d %H:%M:%S')}")
    return {"id": sub.id, "status": sub.status, "aborted_jobs": n}
