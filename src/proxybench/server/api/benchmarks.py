"""Benchmarks, benchmark paths and leaderboards."""

from __future__ import annotations

import time
from typing import Annotated, Literal

from fastapi import APIRouter, Depends, Query, Request, Response
from sqlalchemy import select
from starlette.concurrency import run_in_threadpool

from proxybench.server.api.deps import DB, Caller, require
from proxybench.server.api.schemas import MAX_ID, BenchmarkOut, BenchmarkUpload, LeaderboardOut, PathCreate, PathOut
from proxybench.server.benchmarks import latest, public_view, store_benchmark
from proxybench.server.errors import ServiceError
from proxybench.server.leaderboards import resolve_version
from proxybench.server.models import BenchmarkPath, BenchmarkVersion, User

router = APIRouter(tags=["benchmarks"])
Superuser = Annotated[User, Depends(require())]
Version = Annotated[int | None, Query(ge=1, le=MAX_ID, description="a benchmark version [the newest]")]


@router.post("/benchmarks", status_code=201, response_model=BenchmarkOut)
def upload_benchmark(body: BenchmarkUpload, session: DB, _: Superuser) -> BenchmarkOut:
    """Store a benchmark text (validated); a changed text under a known name becomes a new version."""
    row, created = store_benchmark(session, body.yaml, features=body.features, test_seed=body.test_seed,
                                   hidden_split=body.hidden_split)
    return BenchmarkOut(**public_view(row, True), created=created)


@router.get("/benchmarks", response_model=list[BenchmarkOut], response_model_exclude_unset=True)
def list_benchmarks(session: DB, user: Caller) -> list[dict]:
    """The newest version of every benchmark."""
    rows = session.scalars(select(BenchmarkVersion).order_by(BenchmarkVersion.name, BenchmarkVersion.version))
    newest = {r.name: r for r in rows}
    return [public_view(r, user.role == "superuser") for r in newest.values()]


@router.get("/benchmarks/{name}", response_model=BenchmarkOut, response_model_exclude_unset=True)
def get_benchmark(name: str, session: DB, user: Caller, version: Version = None) -> dict:
    row = latest(session, name) if version is None else session.scalar(
        select(BenchmarkVersion).where(BenchmarkVersion.name == name, BenchmarkVersion.version == version))
    if row is None:
        raise ServiceError(404, f"benchmark {name!r} has no version {version}")
    return public_view(row, user.role == "superuser")


@router.post("/paths", status_code=201, response_model=PathOut)
def create_path(body: PathCreate, session: DB, _: Superuser) -> PathOut:
    """Define a benchmark path (a DAG of steps with conditions). Every step's benchmark must exist."""
    for k, step in enumerate(body.spec.steps):
        try:
            latest(session, step.benchmark)
        except ServiceError:
            raise ServiceError(422, f"spec.steps.{k}.benchmark: no benchmark named {step.benchmark!r}") from None
    if session.scalar(select(BenchmarkPath).where(BenchmarkPath.name == body.name)) is not None:
        raise ServiceError(409, f"a path named {body.name!r} exists")
    session.add(BenchmarkPath(name=body.name, description=body.description, spec=body.spec.model_dump(),
                              created_at=time.time()))
    return PathOut(name=body.name, description=body.description, spec=body.spec)


@router.get("/paths", response_model=list[PathOut])
def list_paths(session: DB, _: Caller) -> list[dict]:
    return [{"name": p.name, "description": p.description, "spec": p.spec}
            for p in session.scalars(select(BenchmarkPath).order_by(BenchmarkPath.name))]


@router.get("/leaderboards/{name}", response_model=LeaderboardOut,
            responses={304: {"description": "not modified since the ETag sent in If-None-Match"}})
async def get_leaderboard(name: str, request: Request, user: Caller,
                          split: Literal["public", "hidden"] = "public", version: Version = None,
                          limit: Annotated[int, Query(ge=1, le=10_000, description="rows per page")] = 100,
                          offset: Annotated[int, Query(ge=0, le=MAX_ID)] = 0) -> Response:
    """Ranked submissions; ``split=hidden`` (test scores) for super-users only. ``limit`` (default 100) and
    ``offset`` page through the rows, best first (``total`` counts them all). Served from the board built
    when it last changed, with an ETag (send it back in If-None-Match: 304 when unchanged).

    The hot path of the server: on the event loop (one indexed query and a dictionary lookup; a thread
    hop would cost more), unless the board must be built first. The query runs on a pooled autocommit
    connection (no ORM session: a third of the cost of the same query through one)."""
    if split == "hidden" and user.role != "superuser":
        raise ServiceError(403, "hidden (test) scores are visible to super-users only")
    with request.app.state.read_engine.connect() as conn:
        bench_id, _, board_version = resolve_version(conn, name, version)
    boards = request.app.state.boards
    served = boards.cached(bench_id, split, board_version)  # a large board being rebuilt: no thread hop either
    board, stale = served if served is not None else await run_in_threadpool(boards.get, bench_id, split,
                                                                              board_version)
    etag = board.etag[:-1] + '-stale"' if stale else board.etag
    headers = {"ETag": etag, "Cache-Control": "private, max-age=1",
               "Last-Modified": time.strftime("%a, %d %b %Y %H:%M:%S GMT", time.gmtime(board.built_at))}
    if request.headers.get("if-none-match") == etag:
        return Response(status_code=304, headers=headers)
    return Response(board.page(offset, limit, stale), media_type="application/json", headers=headers)
