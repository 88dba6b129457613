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
import time

from sqlalchemy import delete, select
from sqlalchemy.orm import Session

from proxybench.server.models import ROLES, ApiToken, User, WebSession

__all__ = ["SESSION_PREFIX", "TOKEN_PREFIX", "close_web_session", "create_user", "csrf_token", "hash_token",
           "issue_token", "open_web_session", "revoke_token", "token_row", "user_for_session", "user_for_token"]

TOKEN_PREFIX = "pbt_"
SESSION_PREFIX = "pbs_"


def hash_token(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()


def issue_token(session: Session, user: User, label: str = "") -> str:
    """A new token for ``user``; the plain text is returned once and never stored."""
    token = TOKEN_PREFIX + secrets.token_urlsafe(32)
    session.add(ApiToken(user=user, token_hash=hash_token(token), prefix=token[:10], label=label,
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


def user_for_token(session: Session, token: str) -> User | None:
    """The user a live token belongs to, or None (unknown or revoked). One indexed query."""
    if not _plausible(token, TOKEN_PREFIX):
        return None
    return session.scalar(select(User).join(ApiToken, ApiToken.user_id == User.id)
                          .where(ApiToken.token_hash == hash_token(token), ApiToken.revoked.is_(False)))


def token_row(session: Session, token: str) -> ApiToken | None:
    """The stored row of a live token, or None."""
    if not _plausible(token, TOKEN_PREFIX):
        return None
    return session.scalar(select(ApiToken).where(ApiToken.token_hash == hash_token(token),
                                                 ApiToken.revoked.is_(False)))


def revoke_token(session: Session, row: ApiToken) -> None:
    """Revoke a token for good; the web sessions opened with it end with it."""
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
