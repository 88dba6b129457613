"""Submissions: built-in agents (JSON) or agent packages (multipart upload); listing, details, retiring."""

from __future__ import annotations

import time
from typing import Annotated

from fastapi import APIRouter, Depends, Form, Path, Request, UploadFile
from sqlalchemy import select
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from proxybench.protocol.package import PackageError, check_archive
from proxybench.server.api.deps import DB, Caller, Conf, require, require_reader, run_write
from proxybench.server.api.schemas import MAX_ID, Retired, SubmissionCreate, SubmissionOut
from proxybench.server.artifacts import TooLarge
from proxybench.server.errors import ServiceError
from proxybench.server.models import ArtifactLink, Submission, User
from proxybench.server.queue import abort_jobs
from proxybench.server.submissions import create_submission
from proxybench.server.views import can_see, submission_view
from proxybench.untrusted import clean_text

router = APIRouter(tags=["submissions"])
Developer = Annotated[User, Depends(require("developer"))]
Uploader = Annotated[User, Depends(require_reader("developer"))]
SubmissionId = Annotated[int, Path(ge=1, le=MAX_ID)]


@router.post("/submissions", status_code=201, response_model=SubmissionOut, response_model_exclude_unset=True)
async def submit_builtin(body: SubmissionCreate, request: Request, settings: Conf, user: Developer) -> dict:
    """Submit a built-in agent to a benchmark or a benchmark path."""

    def work(session: Session) -> dict:
        sub = create_submission(session, user, label=body.label, description=body.description,
                                agent_name=body.agent, benchmark=body.benchmark, path=body.path,
                                daily_limit=settings.daily_submission_limit, max_attempts=settings.max_attempts)
        return submission_view(session, sub, user.role == "superuser", owner=user, new=True)

    return await run_write(request, work)


def _form_text(value: str | None, field: str, limit: int) -> str | None:
    if value is None:
        return None
    if len(value) > limit:
        raise ServiceError(422, f"field {field!r}: at most {limit} characters")
    return clean_text(value)


@router.post("/submissions/upload", status_code=201, response_model=SubmissionOut, response_model_exclude_unset=True)
async def submit_archive(request: Request, settings: Conf, user: Uploader,
                         archive: UploadFile, label: Annotated[str, Form()], description: Annotated[str, Form()] = "",
                         benchmark: Annotated[str | None, Form()] = None,
                         path: Annotated[str | None, Form()] = None) -> dict:
    """Submit an agent package (zip or tar.gz with ``proxybench-agent.yaml``). The archive is checked and
    stored before any database write; the submission is then created in one short transaction."""
    label = _form_text(label, "label", 64) or ""
    description = _form_text(description, "description", 10_000) or ""
    benchmark, path = _form_text(benchmark, "benchmark", 64), _form_text(path, "path", 64)
    name = clean_text(archive.filename or "agent-archive")[:255]
    size = archive.size if archive.size is not None else 0
    if size > settings.archive_max_bytes:
        raise ServiceError(413, f"archive is {size} bytes; the limit is {settings.archive_max_bytes}")
    try:
        manifest = await run_in_threadpool(check_archive, archive.file)
    except PackageError as exc:
        raise ServiceError(422, f"archive {name!r}: {exc}") from None
    store = request.app.state.store

    def _store() -> tuple[str, int]:
        archive.file.seek(0)
        return store.write(iter(lambda: archive.file.read(1 << 20), b""), settings.archive_max_bytes)

    try:
        sha, size = await run_in_threadpool(_store)
    except TooLarge as exc:
        raise ServiceError(413, str(exc)) from None

    def _record(session: Session) -> dict:
        me = session.get(User, user.id)
        store.record(session, sha, size, "application/octet-stream", me.id)
        sub = create_submission(session, me, label=label, description=description, archive_sha256=sha,
                                manifest=manifest, benchmark=benchmark, path=path,
                                daily_limit=settings.daily_submission_limit, max_attempts=settings.max_attempts)
        session.add(ArtifactLink(sha256=sha, submission_id=sub.id, name=name))
        session.flush()
        return submission_view(session, sub, me.role == "superuser", owner=me, new=True)

    return await run_write(request, _record)


@router.get("/submissions", response_model=list[SubmissionOut], response_model_exclude_unset=True)
def list_submissions(session: DB, user: Caller, mine: bool = False) -> list[dict]:
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


@router.get("/submissions/{sid}", response_model=SubmissionOut, response_model_exclude_unset=True)
def get_submission(sid: SubmissionId, session: DB, user: Caller) -> dict:
    """A submission with its jobs and results (hidden scores only for super-users)."""
    return submission_view(session, _own(session, user, sid), user.role == "superuser")


@router.post("/submissions/{sid}/retire", response_model=Retired)
def retire(sid: SubmissionId, session: DB, user: Caller) -> Retired:
    """Withdraw a submission from the leaderboards; its unfinished jobs are aborted, its results kept."""
    sub = _own(session, user, sid)
    sub.status = "retired"
    n = abort_jobs(session, sub, f"retired by {user.name!r} at {time.strftime('%Y-%m-%d %H:%M:%S')}")
    return Retired(id=sub.id, status=sub.status, aborted_jobs=n)
