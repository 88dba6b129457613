"""Submissions: built-in agents (JSON), agent packages or container images (multipart upload); listing, details,
retiring."""

from __future__ import annotations

import shutil
import tempfile
import time
from pathlib import Path as FilePath
from typing import IO, Annotated

from fastapi import APIRouter, Depends, Form, Path, Request, UploadFile
from sqlalchemy import select
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from proxybench.protocol.images import ImageError, ImageLimits, check_image, is_image_archive
from proxybench.protocol.package import AgentManifest, PackageError, check_archive
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
#: how long the check of an uploaded container image may take (skopeo's copy, every layer read once)
IMAGE_CHECK_SECONDS = 300.0


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
    """Submit an agent package (zip or tar.gz with ``proxybench-agent.yaml``) or a container image (an OCI archive
    or a ``docker save`` tarball, told by its content). The archive is checked and stored before any database
    write; the submission is then created in one short transaction."""
    label = _form_text(label, "label", 64) or ""
    description = _form_text(description, "description", 10_000) or ""
    benchmark, path = _form_text(benchmark, "benchmark", 64), _form_text(path, "path", 64)
    name = clean_text(archive.filename or "agent-archive")[:255]
    size = archive.size if archive.size is not None else 0
    image = await run_in_threadpool(is_image_archive, archive.file)
    limit, what = (settings.image_max_bytes, "image_max_bytes") if image else (settings.archive_max_bytes,
                                                                                  "archive_max_bytes")
    if size > limit:
        raise ServiceError(413, f"archive {name!r} is {size} bytes; the server's {what} is {limit}")
    store = request.app.state.store
    try:
        if image:
            manifest = await run_in_threadpool(_check_image, archive.file, name, label, store.root, limit)
        else:
            manifest = await run_in_threadpool(check_archive, archive.file)
    except (PackageError, ImageError) as exc:
        raise ServiceError(422, f"archive {name!r}: {exc}") from None

    def _store() -> tuple[str, int]:
        archive.file.seek(0)
        return store.write(iter(lambda: archive.file.read(1 << 20), b""), limit)

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


def _check_image(f: IO[bytes], name: str, label: str, scratch: FilePath, max_bytes: int) -> AgentManifest:
    """The agent manifest of an uploaded container image, checked as the evaluator checks it before unpacking
    (:func:`~proxybench.protocol.images.check_image`: every blob hashed, every layer read once), in a private
    folder beside the store that is removed afterwards. Errors name the upload, not the folder."""
    with tempfile.TemporaryDirectory(dir=scratch, prefix=".image-check-") as folder:
        path = FilePath(folder) / "image.tar"
        f.seek(0)
        with path.open("wb") as out:
            shutil.copyfileobj(f, out, 1 << 20)
        f.seek(0)
        limits = ImageLimits(max_archive_bytes=max_bytes, max_seconds=IMAGE_CHECK_SECONDS)
        try:
            return check_image(path, label or "image", limits=limits, scratch=folder).manifest
        except ImageError as exc:
            raise ImageError(str(exc).replace(f"image {path}: ", "").replace(str(path), name)) from None


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
