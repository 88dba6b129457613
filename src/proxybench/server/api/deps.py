"""Request dependencies: database sessions (with SQLite's write turn), the caller, role checks, CSRF.

Who is calling: the JSON API takes ``Authorization: Bearer <token>``; it also takes the web console's
session cookie, for reads only (GET / HEAD: artifact downloads and videos in the pages), so no other site
can make a signed-in browser change anything through it. Web pages take the session cookie, and every
form they post must carry the session's CSRF token.
"""

from __future__ import annotations

import hmac
from collections.abc import AsyncIterator, Callable
from typing import Annotated, TypeVar

from fastapi import Depends, Request
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from proxybench.server.config import Settings
from proxybench.server.errors import ServiceError
from proxybench.server.models import User
from proxybench.server.security import TOKEN_PREFIX, csrf_token, hash_token, user_for_session, user_for_token

__all__ = ["DB", "SAFE_METHODS", "SESSION_COOKIE", "Caller", "Conf", "WebCaller", "WebFormCaller",
           "require", "require_reader", "run_write", "session_secret"]

SESSION_COOKIE = "proxybench_session"
SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
T = TypeVar("T")


async def write_turn(request: Request) -> AsyncIterator[None]:
    """Writing requests on SQLite take the write turn (:mod:`..writeturn`) before a worker thread; reads
    (GET) never wait (WAL). Nothing to take on PostgreSQL."""
    turn = request.app.state.write_turn
    if turn is None or request.method in SAFE_METHODS:
        yield
        return
    async with turn.hold():
        yield


async def get_session(request: Request,
                      _turn: Annotated[None, Depends(write_turn, scope="function")]) -> AsyncIterator[Session]:
    """A session per request, committed when the endpoint returns (after its write turn was granted).

    Async on purpose: each sync dependency costs a worker-thread hop (and GIL hand-offs), which under
    load dominated request time; only the endpoint and the commit run in worker threads. GET requests
    never write (the lease reaper, not a page view, returns lapsed leases to the queue), so they use
    autocommit connections: each query is one round trip, with no BEGIN or ROLLBACK around it.
    """
    reading = request.method in SAFE_METHODS
    session = (request.app.state.read_sessions if reading else request.app.state.sessions)()
    try:
        yield session
        if not reading:  # reads write nothing (and run without a transaction: no BEGIN / ROLLBACK trips)
            await run_in_threadpool(_commit_then, request, session)
    except BaseException:
        await run_in_threadpool(session.rollback)
        raise
    finally:
        session.close()


def _commit_then(request: Request, session: Session) -> None:
    """Commit, then what the commit makes due (in one worker-thread hop): leaderboards this transaction
    changed are rebuilt now (small) or scheduled (large); revoked tokens are forgotten once more."""
    session.commit()
    for token_id in session.info.pop("revoked_tokens", ()):  # again after the commit: no request re-cached it
        request.app.state.tokens.forget(token_id=token_id)
    changed = session.info.pop("bumped_boards", None)
    if changed:
        request.app.state.boards.changed(changed)


async def run_write(request: Request, work: Callable[[Session], T]) -> T:
    """``work(session)`` in a worker thread, in one short transaction taken in SQLite's write turn."""
    turn = request.app.state.write_turn

    session = request.app.state.sessions()

    def unit() -> T:
        try:
            out = work(session)
            _commit_then(request, session)
            return out
        except BaseException:
            session.rollback()
            raise

    try:
        if turn is None:
            return await run_in_threadpool(unit)
        async with turn.hold():
            return await run_in_threadpool(unit)
    finally:
        session.close()


def get_settings(request: Request) -> Settings:
    return request.app.state.settings


# scope='function': commit (or roll back) *before* the response is sent, so that a client that got its answer
# (or followed a redirect) reads what it wrote, and a failed commit is an error, not a lost write
DB = Annotated[Session, Depends(get_session, scope="function")]
Conf = Annotated[Settings, Depends(get_settings)]


def _bearer(request: Request) -> str | None:
    auth = request.headers.get("authorization", "")
    if auth[:7].lower() == "bearer ":
        return auth[7:].strip()
    return None


def session_secret(request: Request) -> str | None:
    """The web session's secret from its cookie (None when signed out)."""
    return request.cookies.get(SESSION_COOKIE)


def _api_user(request: Request) -> User:
    token = _bearer(request)
    if token:
        cache = request.app.state.tokens
        user = cache.get(hash_token(token)) if token.startswith(TOKEN_PREFIX) else None
        if user is None:
            with request.app.state.read_sessions() as session:
                user = user_for_token(session, token, cache)
        if user is None:
            raise ServiceError(401, "invalid or revoked API token")
        return user
    secret = session_secret(request)
    if secret and request.method in SAFE_METHODS:
        with request.app.state.read_sessions() as session:
            user = user_for_session(session, secret)
            if user is not None:
                session.expunge(user)
        if user is None:
            raise ServiceError(401, "the web session has expired or was closed; sign in again")
        return user
    raise ServiceError(401, "no API token: send 'Authorization: Bearer <token>'")


async def current_user(request: Request) -> User:
    """The caller; 401 with a clear message when the token is missing, unknown or revoked.

    Most requests are answered by the process's token cache; a lookup (one indexed row) runs on the
    event loop: cheaper than a thread hop. The user comes detached from any session (read its columns)."""
    return _api_user(request)


async def current_reader(request: Request) -> User:
    """The caller, for endpoints that do their writing in :func:`run_write` (the same lookup)."""
    return _api_user(request)


def require(*roles: str) -> Callable[..., User]:
    """A dependency admitting only the given roles (super-users are always admitted)."""

    async def check(user: Annotated[User, Depends(current_user)]) -> User:
        return _admit(user, roles)

    return check


def require_reader(*roles: str) -> Callable[..., User]:
    """:func:`require` for endpoints that do their writing in :func:`run_write`."""

    async def check(user: Annotated[User, Depends(current_reader)]) -> User:
        return _admit(user, roles)

    return check


def _admit(user: User, roles: tuple[str, ...]) -> User:
    if user.role != "superuser" and user.role not in roles:
        raise ServiceError(403, f"user {user.name!r} ({user.role}) may not do this; "
                                f"needs role {' or '.join(('superuser', *roles))}")
    return user


Caller = Annotated[User, Depends(current_user)]


# -- the web console ------------------------------------------------------------------------------------


def web_user(request: Request, session: Session) -> User | None:
    """The signed-in browser's user, or None (no session cookie, expired, signed out, token revoked)."""
    secret = session_secret(request)
    return user_for_session(session, secret) if secret else None


def check_same_origin(request: Request) -> None:
    """Refuse a form posted from another site (the browser says so in Origin / Sec-Fetch-Site)."""
    site = request.headers.get("sec-fetch-site")
    if site is not None and site not in ("same-origin", "none"):
        raise ServiceError(403, f"this form was sent from another site ({site}); open the page here and try again")
    origin = request.headers.get("origin")
    if origin is not None:  # "null" too: a sandboxed frame or a data: page of anyone's
        own = f"{request.url.scheme}://{request.headers.get('host', request.url.netloc)}"
        if origin.rstrip("/") != own:
            raise ServiceError(403, f"this form was sent from {origin}, not from this site; open the page here "
                                    "and try again")


async def _web_caller(request: Request, session: DB) -> User:
    user = web_user(request, session)
    if user is None:
        raise ServiceError(401, "sign in")
    return user


async def _web_form_caller(request: Request, session: DB) -> User:
    """The signed-in user of a form post whose CSRF token matches the session's."""
    user = web_user(request, session)
    if user is None:
        raise ServiceError(401, "sign in")
    check_same_origin(request)
    form = await request.form()
    sent = form.get("csrf")
    secret = session_secret(request) or ""
    if not isinstance(sent, str) or not hmac.compare_digest(sent, csrf_token(secret)):
        raise ServiceError(403, "this form has no valid CSRF token (it is stale, or was not sent from this "
                                "site's page); reload the page and try again")
    return user


WebCaller = Annotated[User, Depends(_web_caller)]
WebFormCaller = Annotated[User, Depends(_web_form_caller)]
