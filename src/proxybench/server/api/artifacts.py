"""Artifacts by content hash: evaluators upload (PUT, hash-checked), owners and super-users download.

An upload holds no database transaction while its bytes arrive: the front door (:mod:`..limits`) has
received, spooled and hashed the whole body before the request is admitted; here the file is checked and
renamed into the store, and one short transaction records it.
"""

from __future__ import annotations

import time
from typing import Annotated

from fastapi import APIRouter, Depends, Query, Request
from fastapi.responses import FileResponse
from sqlalchemy import select
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from proxybench.server.api.deps import DB, Caller, Conf, require_reader, run_write
from proxybench.server.api.schemas import MAX_ID, ArtifactStored
from proxybench.server.artifacts import TooLarge, is_sha256
from proxybench.server.errors import ServiceError
from proxybench.server.limits import BODY_SCOPE_KEY, SpooledBody
from proxybench.server.models import Artifact, ArtifactLink, Evaluator, Job, LeaseArtifact, Submission, User

router = APIRouter(tags=["artifacts"])
Uploader = Annotated[User, Depends(require_reader("evaluator"))]


def _check(sha256: str) -> None:
    if not is_sha256(sha256):
        raise ServiceError(422, f"path: {sha256!r} is not a SHA-256 hex digest (64 lowercase hex digits)")


@router.put("/artifacts/{sha256}", status_code=201, response_model=ArtifactStored)
async def put_artifact(sha256: str, request: Request, settings: Conf, user: Uploader,
                       job_id: Annotated[int | None, Query(ge=1, le=MAX_ID)] = None,
                       lease_id: Annotated[str | None, Query(max_length=64, pattern=r"^[0-9a-f]+$")] = None,
                       ) -> ArtifactStored:
    """Store bytes whose SHA-256 is ``sha256`` (refused if they hash otherwise or exceed the size limit), for the
    result of the lease ``job_id`` / ``lease_id`` (held by one of the caller's evaluators): a result may list
    only artifacts its own lease uploaded."""
    _check(sha256)
    if (job_id is None) != (lease_id is None):
        raise ServiceError(422, "query: give both job_id and lease_id (the lease the artifact belongs to), or neither")
    store = request.app.state.store
    body: SpooledBody | None = request.scope.get(BODY_SCOPE_KEY)
    if body is None:  # served without the front door (never in proxybench serve): read it here
        data = await request.body()
        import hashlib

        body = SpooledBody(size=len(data), sha256=hashlib.sha256(data).hexdigest(), data=data)
    if body.size > settings.artifact_max_bytes:
        raise ServiceError(413, f"artifact exceeds the limit of {settings.artifact_max_bytes} bytes")
    if body.sha256 != sha256:
        raise ServiceError(422, f"content hash is {body.sha256}, not the {sha256} named in the request")
    try:
        if body.path is not None:
            size = await run_in_threadpool(store.adopt, body.path, sha256, body.size)
        else:
            _, size = await run_in_threadpool(store.write, [body.data or b""], settings.artifact_max_bytes, sha256)
    except TooLarge as exc:
        raise ServiceError(413, str(exc)) from None
    except ValueError as exc:
        raise ServiceError(422, str(exc)) from None
    media = request.headers.get("content-type", "application/octet-stream")[:128]

    def _record(session: Session) -> None:
        store.record(session, sha256, size, media, user.id)
        if job_id is not None and lease_id is not None:
            _record_for_lease(session, user, job_id, lease_id, sha256)

    await run_write(request, _record)
    return ArtifactStored(sha256=sha256, size=size)


def _record_for_lease(session: Session, user: User, job_id: int, lease_id: str, sha256: str) -> None:
    held = session.scalar(select(Job.id).join(Evaluator, Job.evaluator_id == Evaluator.id)
                          .where(Job.id == job_id, Job.status == "evaluating", Job.lease_id == lease_id,
                                 Evaluator.user_id == user.id))
    if held is None:
        raise ServiceError(409, f"job {job_id}: lease {lease_id[:8]}… is not held by an evaluator of {user.name!r}; "
                                "stop working on it")
    known = session.scalar(select(LeaseArtifact.id).where(LeaseArtifact.job_id == job_id,
                                                          LeaseArtifact.lease_id == lease_id,
                                                          LeaseArtifact.sha256 == sha256))
    if known is None:
        session.add(LeaseArtifact(job_id=job_id, lease_id=lease_id, sha256=sha256, created_at=time.time()))


def uploaded_under(session: Session, job_id: int, lease_id: str) -> set[str]:
    """The artifacts uploaded under this lease: the only ones its result may name."""
    return set(session.scalars(select(LeaseArtifact.sha256).where(LeaseArtifact.job_id == job_id,
                                                                  LeaseArtifact.lease_id == lease_id)))


def _may_read(session: DB, user: User, sha256: str) -> bool:
    if user.role == "superuser":
        return True
    links = session.scalars(select(ArtifactLink).where(ArtifactLink.sha256 == sha256)).all()
    if user.role == "evaluator":  # the archive of a job it holds a lease on now, and what it uploaded itself
        art = session.get(Artifact, sha256)
        if art is not None and art.uploaded_by == user.id:
            return True
        subs = {ln.submission_id for ln in links if ln.result_id is None}
        mine = select(Evaluator.id).where(Evaluator.user_id == user.id)
        return bool(subs) and session.scalar(
            select(Job.id).where(Job.submission_id.in_(subs), Job.status == "evaluating",
                                 Job.evaluator_id.in_(mine)).limit(1)) is not None
    for ln in links:
        sub = session.get(Submission, ln.submission_id)
        if sub is not None and sub.user_id == user.id and not ln.hidden:
            return True
    return False


@router.get("/artifacts/{sha256}", response_class=FileResponse,
            responses={200: {"description": "the file's bytes, with its media type"}})
def get_artifact(sha256: str, request: Request, session: DB, user: Caller) -> FileResponse:
    """Download an artifact: yours (not hidden), the archive of a job you hold a lease on (evaluators),
    anything (super-users)."""
    _check(sha256)
    art = session.get(Artifact, sha256)
    if art is None:
        raise ServiceError(404, f"no artifact {sha256}")
    if not _may_read(session, user, sha256):
        raise ServiceError(403, f"artifact {sha256[:12]}… belongs to another user's submission or is hidden")
    link = session.scalar(select(ArtifactLink).where(ArtifactLink.sha256 == sha256).limit(1))
    name = link.name.rsplit("/", 1)[-1] if link is not None else sha256
    return FileResponse(request.app.state.store.path(sha256), media_type=art.media_type, filename=name)
