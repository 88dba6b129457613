"""Request dependencies: the database session, the caller (from the API token) and role checks."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Annotated

from fastapi import Depends, Request
from sqlalchemy.orm import Session

from proxybench.server.config import Settings
from proxybench.server.db import session_scope
from proxybench.server.errors import ServiceError
from proxybench.server.models import User
from proxybench.server.security import user_for_token

__all__ = ["DB", "Caller", "Conf", "require"]

TOKEN_COOKIE = "proxybench_token"


def get_session(request: Request) -> Iterator[Session]:
    """A session per request; on SQLite, writing requests take turns (see :func:`write_turn`)."""
    with write_turn(request.app, request.method), session_scope(request.app.state.sessions) as session:
        yield session


@contextmanager
def write_turn(app, method: str) -> Iterator[None]:
    """SQLite allows one writer: queue writers on a lock instead of SQLite's busy-wait, which sleeps in
    steps of up to 100 ms and made p99 latency seconds under load. Reads (GET) never wait (WAL)."""
    lock = app.state.write_lock
    if lock is None or method in ("GET", "HEAD", "OPTIONS"):
        yield
        return
    with lock:
        yield


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


def current_user(request: Request, session: DB) -> User:
    """The caller; 401 with a clear message when the token is missing, unknown or revoked."""
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

    def check(user: Annotated[User, Depends(current_user)]) -> User:
        if user.role != "superuser" and user.role not in roles:
            raise ServiceError(403, f"user {user.name!r} ({user.role}) may not do this; "
                                    f"needs role {' or '.join(('superuser', *roles))}")
        return user

    return check


Caller = Annotated[User, Depends(current_user)]
