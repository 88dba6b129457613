"""Request dependencies: the database session, the caller (from the API token) and role checks."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator, Callable
from typing import Annotated

from fastapi import Depends, Request
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from proxybench.server.config import Settings
from proxybench.server.errors import ServiceError
from proxybench.server.models import User
from proxybench.server.security import user_for_token

__all__ = ["DB", "Caller", "Conf", "require"]

TOKEN_COOKIE = "proxybench_token"


def write_lock(app) -> asyncio.Lock | None:
    """The SQLite writers' lock of the running event loop (None on PostgreSQL: row locks suffice)."""
    locks = app.state.write_locks
    if locks is None:
        return None
    loop = asyncio.get_running_loop()
    if loop not in locks:
        locks[loop] = asyncio.Lock()
    return locks[loop]


async def write_turn(request: Request) -> AsyncIterator[None]:
    """SQLite allows one writer: writing requests queue on an event-loop lock *before* they take a worker
    thread. (SQLite's own busy-wait sleeps in steps of up to 100 ms: p99 of seconds under load; a thread
    lock deadlocked once waiting writers held every worker thread.) Reads (GET) never wait (WAL)."""
    lock = write_lock(request.app)
    if lock is None or request.method in ("GET", "HEAD", "OPTIONS"):
        yield
        return
    async with lock:
        yield


async def get_session(request: Request,
                      _turn: Annotated[None, Depends(write_turn, scope="function")]) -> AsyncIterator[Session]:
    """A session per request, committed when the endpoint returns (after its write turn was granted).

    Async on purpose: each sync dependency costs a worker-thread hop (and GIL hand-offs), which under
    load dominated request time; only the endpoint and the commit run in worker threads.
    """
    session = request.app.state.sessions()
    try:
        yield session
        await run_in_threadpool(session.commit)
    except BaseException:
        await run_in_threadpool(session.rollback)
        raise
    finally:
        session.close()


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


# scope='function': commit (or roll back) *before* the response is sent, so that a client that got its answer
# (or followed a redirect) reads what it wrote, and a failed commit is an error, not a lost write
DB = Annotated[Session, Depends(get_session, scope="function")]
Conf = Annotated[Settings, Depends(get_settings)]


def _token(request: Request) -> str | None:
    auth = request.headers.get("authorization", "")
    if auth.lower().startswith("bearer "):
        return auth[7:].strip()
    return request.cookies.get(TOKEN_COOKIE)


async def current_user(request: Request, session: DB) -> User:
    """The caller; 401 with a clear message when the token is missing, unknown or revoked.

    The token lookup (one indexed row) runs on the event loop: cheaper than a thread hop."""
    token = _token(request)
    if not token:
        raise ServiceError(401, "no API token: send 'Authorization: Bearer <token>'")
    user = user_for_token(session, token)
    if user is None:
        raise ServiceError(401, "invalid or revoked API token")
    return user


def optional_user(request: Request, session: DB) -> User | None:
    token = _token(request)
    return user_for_token(session, token) if token else None


def require(*roles: str) -> Callable[..., User]:
    """A dependency admitting only the given roles (super-users are always admitted)."""

    async def check(user: Annotated[User, Depends(current_user)]) -> User:
        if user.role != "superuser" and user.role not in roles:
            raise ServiceError(403, f"user {user.name!r} ({user.role}) may not do this; "
                                    f"needs role {' or '.join(('superuser', *roles))}")
        return user

    return check


Caller = Annotated[User, Depends(current_user)]
