"""API tokens: random secrets shown once, stored as SHA-256 hashes; roles scope what a token may do.

Tokens carry 256 bits of randomness, so a fast hash is enough (no password stretching needed): a leaked
database does not leak usable tokens.
"""

from __future__ import annotations

import hashlib
import secrets
import time

from sqlalchemy import select
from sqlalchemy.orm import Session

from proxybench.server.models import ROLES, ApiToken, User

__all__ = ["TOKEN_PREFIX", "create_user", "hash_token", "issue_token", "user_for_token"]

TOKEN_PREFIX = "pbt_"


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
    if not name or len(name) > 64 or not name.replace("-", "").replace("_", "").replace(".", "").isalnum():
        raise ValueError(f"user name must be 1-64 letters, digits, '-', '_' or '.', got {name!r}")
    if session.scalar(select(User).where(User.name == name)) is not None:
        raise ValueError(f"user {name!r} already exists")
    user = User(name=name, role=role, created_at=time.time(), daily_limit=daily_limit)
    session.add(user)
    session.flush()
    return user, issue_token(session, user, label="first")


def user_for_token(session: Session, token: str) -> User | None:
    """The user a live token belongs to, or None (unknown or revoked)."""
    if not token.startswith(TOKEN_PREFIX):
        return None
    return session.scalar(select(User).join(ApiToken, ApiToken.user_id == User.id)
                          .where(ApiToken.token_hash == hash_token(token), ApiToken.revoked.is_(False)))
