"""The challenges server as a FastAPI app, built by :func:`create_app` from :class:`Settings`.

At start it migrates the database to the newest schema, registers the built-in benchmarks (a changed
file becomes a new version) and, on an empty database, creates the super-user ``admin`` whose token is
written to ``<data_dir>/admin.token`` (mode 600). JSON API under ``/api/v1`` (OpenAPI at
``/api/v1/openapi.json``, docs at ``/api/v1/docs``); web pages at ``/``.

With several worker processes (``Settings.workers``), ``proxybench serve`` prepares the database once
(:func:`prepare`) and each worker builds its app with :func:`app_from_env` from the same settings.
"""

from __future__ import annotations

import asyncio
import os
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from pathlib import Path

import anyio.to_thread
from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from sqlalchemy import func, select
from sqlalchemy.orm import sessionmaker
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException

from proxybench import __version__
from proxybench.server.artifacts import ArtifactStore
from proxybench.server.benchmarks import register_builtins
from proxybench.server.config import Settings
from proxybench.server.connections import configure as configure_connections
from proxybench.server.connections import raise_open_files
from proxybench.server.db import make_engine, migrate, session_scope
from proxybench.server.errors import ServiceError
from proxybench.server.leaderboards import BoardCache
from proxybench.server.limits import BodyRules, RequestGate
from proxybench.server.models import User
from proxybench.server.queue import install_board_bumps
from proxybench.server.security import TokenCache, create_user
from proxybench.server.writeturn import WriteTurn

__all__ = ["app_from_env", "bootstrap", "create_app", "prepare"]

API = "/api/v1"


def bootstrap(settings: Settings, factory: sessionmaker) -> str | None:
    """Built-in benchmarks, and the first super-user on an empty database (returns its new token)."""
    with session_scope(factory) as session:
        register_builtins(session)
        if session.scalar(select(func.count()).select_from(User)):
            return None
        _, token = create_user(session, "admin", "superuser")
    path = settings.data_dir / "admin.token"
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(token + "\n")
    return token


def _validation_message(exc: RequestValidationError) -> str:
    parts = []
    for err in exc.errors()[:10]:
        loc = ".".join(str(p) for p in err.get("loc", ()) if p != "body") or "body"
        parts.append(f"{loc}: {err.get('msg', 'invalid')}")
    return "; ".join(parts)


def prepare(settings: Settings) -> str | None:
    """Once per server (not per worker): migrate the database, register built-ins, make the first
    super-user. Returns the new admin token on an empty database."""
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    engine = make_engine(settings.url, pool_size=2)
    try:
        migrate(engine)
        return bootstrap(settings, sessionmaker(engine, expire_on_commit=False))
    finally:
        engine.dispose()


def app_from_env() -> FastAPI:
    """A worker's app (``uvicorn --factory``): settings from ``PROXYBENCH_SERVER_*``, database prepared."""
    return create_app(Settings.from_env(), prepared=True)


async def _has_valid_token(app: FastAPI, scope: dict) -> bool:
    """Whether a request carries a live API token (checked before a large upload's body is read)."""
    from proxybench.server.security import hash_token, user_for_token

    auth = dict(scope.get("headers") or []).get(b"authorization", b"").decode("latin-1")
    if auth[:7].lower() != "bearer ":
        return False
    token = auth[7:].strip()
    if app.state.tokens.get(hash_token(token)) is not None:
        return True

    def lookup() -> bool:
        with app.state.read_sessions() as session:
            return user_for_token(session, token, app.state.tokens) is not None

    return await run_in_threadpool(lookup)


def _requeue(app: FastAPI) -> None:
    from proxybench.server.queue import requeue_expired

    with session_scope(app.state.sessions) as session:
        requeue_expired(session)


async def _reap(app: FastAPI) -> None:
    """Return lapsed leases to the queue even when no evaluator asks for work (the queue page stays true)."""
    period = max(0.5, app.state.settings.lease_seconds / 4)
    while True:
        await asyncio.sleep(period)
        try:
            turn = app.state.write_turn
            if turn is None:
                await run_in_threadpool(_requeue, app)
            else:
                async with turn.hold():
                    await run_in_threadpool(_requeue, app)
        except Exception as exc:  # a database hiccup must not kill the reaper
            print(f"lease reaper: {exc}", file=sys.stderr)


def _warm_up() -> None:
    """Load the compiled leaderboard kernel now: its first call imports Numba and loads the machine code
    (~0.5 s holding the interpreter), which under load stalled every request of the process."""
    import numpy as np

    from proxybench.tasks.scoring import Criterion, copeland_counts

    copeland_counts(np.zeros((2, 1)), [Criterion("warm-up", True, 0.0)])


@asynccontextmanager
async def _lifespan(app: FastAPI) -> AsyncIterator[None]:
    # worker threads for every admitted request (see RequestGate), the board builder and the reaper
    anyio.to_thread.current_default_thread_limiter().total_tokens = app.state.settings.max_concurrent_requests + 2
    await run_in_threadpool(_warm_up)  # before the process takes requests
    reaper = asyncio.create_task(_reap(app))
    try:
        yield
    finally:
        reaper.cancel()
        app.state.boards.close()
        if app.state.write_turn is not None:
            app.state.write_turn.close()
        app.state.engine.dispose()
        app.state.read_engine.dispose()


def create_app(settings: Settings | None = None, *, prepared: bool = False) -> FastAPI:
    """A ready server: database migrated, built-ins registered, routes mounted (``prepared``: the first two
    were done by :func:`prepare` already, as for the workers of a multi-process server)."""
    settings = settings or Settings.from_env()
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    engine = make_engine(settings.url, pool_size=settings.max_concurrent_requests + 4)
    # reads (GET) on autocommit connections of their own: one round trip per query, nothing to reset. At most
    # max_concurrent_requests GETs run at once (admission), so that many connections suffice; only half are kept
    # open, so that 4 workers keep (12 + 4) × 4 = 64 connections, well under PostgreSQL's default 100
    half = max(1, settings.max_concurrent_requests // 2)
    read_engine = make_engine(settings.url, pool_size=half, autocommit=True,
                              max_overflow=settings.max_concurrent_requests - half)
    if not prepared:
        migrate(engine)
    factory = sessionmaker(engine, expire_on_commit=False)
    install_board_bumps(factory)
    app = FastAPI(title="proxybench challenges server", version=__version__, openapi_url=f"{API}/openapi.json",
                  docs_url=f"{API}/docs", redoc_url=None, lifespan=_lifespan)
    app.state.settings = settings
    app.state.engine = engine
    app.state.sessions = factory
    app.state.read_engine = read_engine
    app.state.read_sessions = sessionmaker(read_engine, expire_on_commit=False)
    app.state.store = ArtifactStore(settings.artifact_dir)
    sqlite = settings.url.startswith("sqlite")
    app.state.write_turn = WriteTurn(settings.data_dir / "write.lock" if settings.workers > 1 else None) \
        if sqlite else None
    app.state.boards = BoardCache(factory)
    app.state.tokens = TokenCache(settings.token_cache_seconds)
    app.state.admin_token = None if prepared else bootstrap(settings, factory)
    configure_connections(settings.header_timeout, settings.max_connections_per_address)
    raise_open_files()
    rules = BodyRules(limits=[(f"{API}/artifacts/", settings.artifact_max_bytes),
                              (f"{API}/submissions/upload",
                               max(settings.archive_max_bytes, settings.image_max_bytes) + (1 << 20))],
                      default=settings.json_max_bytes, timeout=settings.body_timeout,
                      min_rate=settings.body_min_rate, spool_dir=settings.data_dir / "spool",
                      max_readers_per_address=settings.max_readers_per_address)
    for stale in rules.spool_dir.glob(".body-*") if not prepared else ():  # left by a killed server
        stale.unlink(missing_ok=True)
    app.add_middleware(RequestGate, body=rules, concurrency=settings.max_concurrent_requests,
                       queue=settings.max_queued_requests, send_timeout=settings.send_timeout,
                       authorize=lambda scope: _has_valid_token(app, scope))

    @app.exception_handler(ServiceError)
    async def _service_error(_: Request, exc: ServiceError) -> JSONResponse:
        return JSONResponse({"detail": exc.message}, status_code=exc.status)

    @app.exception_handler(HTTPException)
    async def _http_error(_: Request, exc: HTTPException) -> JSONResponse:
        detail = exc.detail
        if exc.status_code == 400 and detail == "There was an error parsing the body":
            detail = "the request body could not be parsed (malformed, or nested too deeply)"
        return JSONResponse({"detail": detail}, status_code=exc.status_code, headers=exc.headers)

    @app.exception_handler(RequestValidationError)
    async def _invalid(_: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [{"loc": list(e.get("loc", ())), "msg": e.get("msg", ""), "type": e.get("type", "")}
                  for e in exc.errors()[:10]]
        return JSONResponse({"detail": _validation_message(exc), "errors": errors}, status_code=422)

    from proxybench.server.api import artifacts, benchmarks, jobs, submissions, users
    from proxybench.server.api.schemas import Health

    for module in (users, benchmarks, submissions, jobs, artifacts):
        app.include_router(module.router, prefix=API)

    @app.get(f"{API}/health", tags=["health"], response_model=Health)
    async def health() -> Health:
        """Liveness: answers without touching the database."""
        return Health(status="ok", version=__version__)

    web = Path(__file__).with_name("web")
    if (web / "__init__.py").exists():
        from proxybench.server.web import mount

        mount(app)
    return app
