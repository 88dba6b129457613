"""Artifacts by content hash: evaluators upload (PUT, hash-checked), owners and super-users download."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Request
from fastapi.responses import FileResponse
from sqlalchemy import select

from proxybench.server.api.deps import DB, Caller, Conf, require
from proxybench.server.artifacts import TooLarge, is_sha256
from proxybench.server.errors import ServiceError
from proxybench.server.models import Artifact, ArtifactLink, Job, Submission, User

router = APIRouter(tags=["artifacts"])
EvaluatorUser = Annotated[User, Depends(require("evaluator"))]


def _check(sha256: str) -> None:
    if not is_sha256(sha256):
        raise ServiceError(422, f"path: {sha256!r} is not a SHA-256 hex digest (64 lowercase hex digits)")


@router.put("/artifacts/{sha256}", status_code=201)
async def put_artifact(sha256: str, request: Request, session: DB, settings: Conf,
                       user: EvaluatorUser) -> dict[str, Any]:
    """Store bytes whose SHA-256 is ``sha256`` (refused if they hash otherwise or exceed the size limit)."""
    _check(sha256)
    store = request.app.state.store
    length = request.headers.get("content-length")
    if length is not None and length.isdigit() and int(length) > settings.artifact_max_bytes:
        raise ServiceError(413, f"artifact is {length} bytes; the limit is {settings.artifact_max_bytes}")
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > settings.artifact_max_bytes:
            raise ServiceError(413, f"artifact exceeds the limit of {settings.artifact_max_bytes} bytes")
    try:
        sha, size = store.write([bytes(body)], settings.artifact_max_bytes, expected=sha256)
    except TooLarge as exc:
        raise ServiceError(413, str(exc)) from None
    except ValueError as exc:
        raise ServiceError(422, str(exc)) from None
    media = request.headers.get("content-type", "application/octet-stream")[:128]
    store.record(session, sha, size, media, user.id)
    return {"sha256": sha, "size": size}


def _may_read(session: DB, user: User, sha256: str) -> bool:
    if user.role == "superuser":
        return True
    links = session.scalars(select(ArtifactLink).where(ArtifactLink.sha256 == sha256)).all()
    if user.role == "evaluator":  # the archives of jobs it may run, and what it uploaded itself
        art = session.get(Artifact, sha256)
        if art is not None and art.uploaded_by == user.id:
            return True
        subs = {ln.submission_id for ln in links if ln.result_id is None}
        return bool(subs) and session.scalar(select(Job.id).where(Job.submission_id.in_(subs)).limit(1)) is not None
    for ln in links:
        sub = session.get(Submission, ln.submission_id)
        if sub is not None and sub.user_id == user.id and not ln.hidden:
            return True
    return False


@router.get("/artifacts/{sha256}")
def get_artifact(sha256: str, request: Request, session: DB, user: Caller) -> FileResponse:
    """Download an artifact: yours (not hidden), a job's archive (evaluators), anything (super-users)."""
    _check(sha256)
    art = session.get(Artifact, sha256)
    if art is None:
        raise ServiceError(404, f"no artifact {sha256}")
    if not _may_read(session, user, sha256):
        raise ServiceError(403, f"artifact {sha256[:12]}… belongs to another user's submission or is hidden")
    link = session.scalar(select(ArtifactLink).where(ArtifactLink.sha256 == sha256).limit(1))
    name = link.name.rsplit("/", 1)[-1] if link is not None else sha256
    return FileResponse(request.app.state.store.path(sha256), media_type=art.media_type, filename=name)
