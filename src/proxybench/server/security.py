"""API tokens and web sessions: random secrets shown once, stored as SHA-256 hashes; roles scope what a
token may do; tokens can be revoked; a browser gets its own expiring session secret, never the token.

Secrets carry 256 bits of randomness, so a fast hash is enough (no password stretching needed): a leaked
database does not leak usable tokens or sessions. The web console's forms carry a CSRF token derived from
the session secret (HMAC), which another site can neither read nor guess.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
import time

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from proxybench.server.models import ROLES, ApiToken, User, WebSession

__all__ = ["SESSION_PREFIX", "TOKEN_PREFIX", "TokenCache", "close_web_session", "create_user", "csrf_token",
           "hash_token", "issue_token", "open_web_session", "revoke_token", "token_row", "user_for_session",
           "user_for_token"]

TOKEN_PREFIX = "pbt_"
SESSION_PREFIX = "pbs_"


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def issue_token(session: Session, user: User, label: str = "") -> str:
    """A new token for ``user``; the plain text is returned once and never stored."""
    token = TOKEN_PREFIX + secrets.token_urlsafe(32)
    session.add(ApiToken(user_id=user.id, token_hash=hash_token(token), prefix=token[:10], label=label,
                         created_at=time.time()))
    return token


def create_user(session: Session, name: str, role: str, daily_limit: int | None = None) -> tuple[User, str]:
    """A user with a first token. Raises ValueError on a bad role or a name already taken."""
    if role not in ROLES:
        raise ValueError(f"role must be one of {', '.join(ROLES)}, got {role!r}")
    if not name or len(name) > 64 or not name.replace("-", "").replace("_", "").replace(".", "").isalnum() \
            or not name.isascii():
        raise ValueError(f"user name must be 1-64 letters, digits, '-', '_' or '.', got {name!r}")
    if session.scalar(select(User).where(User.name == name)) is not None:
        raise ValueError(f"user {name!r} already exists")
    user = User(name=name, role=role, created_at=time.time(), daily_limit=daily_limit)
    session.add(user)
    session.flush()
    return user, issue_token(session, user, label="first")


def _plausible(secret: str, prefix: str) -> bool:
    return secret.startswith(prefix) and 10 < len(secret) < 200 and secret.isascii()


def user_for_token(session: Session, token: str, cache: TokenCache | None = None) -> User | None:
    """The user a live token belongs to, or None (unknown or revoked). One indexed query, or none when
    ``cache`` knows the token (the user then comes detached from any session: read its columns only)."""
    if not _plausible(token, TOKEN_PREFIX):
        return None
    digest = hash_token(token)
    if cache is not None:
        hit = cache.get(digest)
        if hit is not None:
            return hit
    row = session.execute(select(User, ApiToken.id).join(ApiToken, ApiToken.user_id == User.id)
                          .where(ApiToken.token_hash == digest, ApiToken.revoked.is_(False))).first()
    if row is None:
        return None
    user, token_id = row
    if cache is not None:
        session.expunge(user)
        cache.put(digest, user, token_id)
    return user


class TokenCache:
    """Live tokens this process looked up in the last ``ttl`` seconds: most requests need no token query.

    Revoking a token drops it here at once; other server processes stop accepting it within ``ttl``
    seconds (their entries expire). ``ttl = 0`` turns the cache off."""

    def __init__(self, ttl: float, size: int = 4096) -> None:
        self.ttl = ttl
        self.size = size
        self._entries: dict[str, tuple[User, int, float]] = {}
        self._lock = threading.Lock()

    def get(self, digest: str) -> User | None:
        entry = self._entries.get(digest)
        if entry is None or entry[2] < time.monotonic():
            return None
        return entry[0]

    def put(self, digest: str, user: User, token_id: int) -> None:
        if self.ttl <= 0:
            return
        with self._lock:
            if len(self._entries) >= self.size:
                now = time.monotonic()
                self._entries = {k: v for k, v in self._entries.items() if v[2] >= now}
                if len(self._entries) >= self.size:
                    self._entries.clear()
            self._entries[digest] = (user, token_id, time.monotonic() + self.ttl)

    def forget(self, token_id: int | None = None, user_id: int | None = None) -> None:
        """Drop a token's entry (or every entry of a user's)."""
        with self._lock:
            self._entries = {k: v for k, v in self._entries.items()
                             if v[1] != token_id and (user_id is None or v[0].id != user_id)}


def token_row(session: Session, token: str) -> ApiToken | None:
    """The stored row of a live token, or None."""
    if not _plausible(token, TOKEN_PREFIX):
        return None
    return session.scalar(select(ApiToken).where(ApiToken.token_hash == hash_token(token),
                                                 ApiToken.revoked.is_(False)))


def revoke_token(session: Session, row: ApiToken, cache: TokenCache | None = None) -> None:
    """Revoke a token for good; the web sessions opened with it end with it."""
    if cache is not None:
        cache.forget(token_id=row.id)
    session.info.setdefault("revoked_tokens", set()).add(row.id)
    if not row.revoked:
        row.revoked = True
        row.revoked_at = time.time()
    session.execute(delete(WebSession).where(WebSession.token_id == row.id))


def open_web_session(session: Session, token: ApiToken, lifetime: float) -> str:
    """A browser session for the token's user, valid ``lifetime`` seconds; returns its secret (the cookie)."""
    secret = SESSION_PREFIX + secrets.token_urlsafe(32)
    now = time.time()
    session.execute(delete(WebSession).where(WebSession.expires_at < now))  # tidy up expired ones
    session.add(WebSession(secret_hash=hash_token(secret), user_id=token.user_id, token_id=token.id,
                           created_at=now, expires_at=now + lifetime))
    return secret


def user_for_session(session: Session, secret: str) -> User | None:
    """The user of a live session (not expired, its token not revoked), or None. One indexed query."""
    if not _plausible(secret, SESSION_PREFIX):
        return None
    return session.scalar(select(User).join(WebSession, WebSession.user_id == User.id)
                          .join(ApiToken, ApiToken.id == WebSession.token_id)
                          .where(WebSession.secret_hash == hash_token(secret), WebSession.expires_at > time.time(),
                                 ApiToken.revoked.is_(False)))


def close_web_session(session: Session, secret: str) -> None:
    if _plausible(secret, SESSION_PREFIX):
        session.execute(delete(WebSession).where(WebSession.secret_hash == hash_token(secret)))


def csrf_token(secret: str) -> str:
    """The CSRF token of the forms of a session (or of the sign-in form's own cookie)."""
    return hmac.new(secret.encode(), b"proxybench-csrf", hashlib.sha256).hexdigest()[:32]
