"""Benchmarks, benchmark paths and leaderboards."""

from __future__ import annotations

import time
from typing import Annotated, Any

from fastapi import APIRouter, Depends
from sqlalchemy import select

from proxybench.server.api.deps import DB, Caller, require
from proxybench.server.api.schemas import BenchmarkUpload, PathCreate
from proxybench.server.benchmarks import latest, public_view, store_benchmark
from proxybench.server.errors import ServiceError
from proxybench.server.leaderboards import leaderboard_rows
from proxybench.server.models import BenchmarkPath, BenchmarkVersion, User

router = APIRouter(tags=["benchmarks"])
Superuser = Annotated[User, Depends(require())]


@router.post("/benchmarks", status_code=201)
def upload_benchmark(body: BenchmarkUpload, session: DB, _: Superuser) -> dict[str, Any]:
    """Store a benchmark text (validated); a changed text under a known name becomes a new version."""
    row, created = store_benchmark(session, body.yaml, features=body.features, test_seed=body.test_seed,
                                   hidden_split=body.hidden_split)
    return {**public_view(row, True), "created": created}


@router.get("/benchmarks")
def list_benchmarks(session: DB, user: Caller) -> list[dict[str, Any]]:
    """The newest version of every benchmark."""
    rows = session.scalars(select(BenchmarkVersion).order_by(BenchmarkVersion.name, BenchmarkVersion.version))
    newest = {r.name: r for r in rows}
    return [public_view(r, user.role == "superuser") for r in newest.values()]


@router.get("/benchmarks/{name}")
def get_benchmark(name: str, session: DB, user: Caller, version: int | None = None) -> dict[str, Any]:
    row = latest(session, name) if version is None else session.scalar(
        select(BenchmarkVersion).where(BenchmarkVersion.name == name, BenchmarkVersion.version == version))
    if row is None:
        raise ServiceError(404, f"benchmark {name!r} has no version {version}")
    return public_view(row, user.role == "superuser")


@router.post("/paths", status_code=201)
def create_path(body: PathCreate, session: DB, _: Superuser) -> dict[str, Any]:
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
    return {"name": body.name, "spec": body.spec.model_dump()}


@router.get("/paths")
def list_paths(session: DB, _: Caller) -> list[dict[str, Any]]:
    return [{"name": p.name, "description": p.description, "spec": p.spec}
            for p in session.scalars(select(BenchmarkPath).order_by(BenchmarkPath.name))]


@router.get("/leaderboards/{name}")
def get_leaderboard(name: str, session: DB, user: Caller, split: str = "public",
                    version: int | None = None) -> dict[str, Any]:
    """Ranked submissions; ``split=hidden`` (test scores) for super-users only."""
    if split == "hidden" and user.role != "superuser":
        raise ServiceError(403, "hidden (test) scores are visible to super-users only")
    return leaderboard_rows(session, name, split, version)
