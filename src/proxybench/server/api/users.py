"""Users and tokens: super-users create accounts; everyone sees who they are, mints, lists and revokes
their own tokens (super-users: anyone's)."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Depends, Path, Request
from sqlalchemy import select

from proxybench.server.api.deps import DB, Caller, require
from proxybench.server.api.schemas import MAX_ID, TokenCreate, TokenCreated, TokenOut, UserCreate, UserCreated, UserOut
from proxybench.server.errors import ServiceError
from proxybench.server.models import ApiToken, User
from proxybench.server.security import create_user, hash_token, issue_token, revoke_token

router = APIRouter(tags=["users"])
Superuser = Annotated[User, Depends(require())]
TokenId = Annotated[int, Path(ge=1, le=MAX_ID, description="a token's id (GET /me/tokens)")]


def _user_view(u: User) -> UserOut:
    return UserOut(name=u.name, role=u.role, daily_limit=u.daily_limit, created_at=u.created_at)


def _token_view(t: ApiToken, owner: str) -> TokenOut:
    return TokenOut(id=t.id, user=owner, prefix=t.prefix, label=t.label, created_at=t.created_at,
                    revoked=t.revoked, revoked_at=t.revoked_at)


@router.get("/me", response_model=UserOut)
def me(user: Caller) -> UserOut:
    """Who this token belongs to."""
    return _user_view(user)


@router.post("/users", status_code=201, response_model=UserCreated)
def add_user(body: UserCreate, session: DB, _: Superuser) -> UserCreated:
    """Create a user (super-users only). The token in the reply is shown once."""
    try:
        user, token = create_user(session, body.name, body.role, body.daily_limit)
    except ValueError as exc:
        raise ServiceError(409 if "exists" in str(exc) else 422, str(exc)) from None
    return UserCreated(**_user_view(user).model_dump(), token=token)


@router.get("/users", response_model=list[UserOut])
def list_users(session: DB, _: Superuser) -> list[UserOut]:
    return [_user_view(u) for u in session.scalars(select(User).order_by(User.id))]


@router.post("/me/tokens", status_code=201, response_model=TokenCreated)
def new_token(body: TokenCreate, session: DB, user: Caller) -> TokenCreated:
    """Another token for the caller (e.g. one per machine). Shown once."""
    token = issue_token(session, user, body.label)
    session.flush()
    row = session.scalar(select(ApiToken).where(ApiToken.token_hash == hash_token(token)))
    return TokenCreated(**_token_view(row, user.name).model_dump(), token=token)


@router.get("/me/tokens", response_model=list[TokenOut])
def my_tokens(session: DB, user: Caller) -> list[TokenOut]:
    """The caller's tokens (never their text: only a prefix), revoked ones included."""
    rows = session.scalars(select(ApiToken).where(ApiToken.user_id == user.id).order_by(ApiToken.id))
    return [_token_view(t, user.name) for t in rows]


@router.get("/users/{name}/tokens", response_model=list[TokenOut])
def user_tokens(name: str, session: DB, _: Superuser) -> list[TokenOut]:
    """Super-users: a user's tokens."""
    owner = session.scalar(select(User).where(User.name == name))
    if owner is None:
        raise ServiceError(404, f"no user {name!r}")
    rows = session.scalars(select(ApiToken).where(ApiToken.user_id == owner.id).order_by(ApiToken.id))
    return [_token_view(t, owner.name) for t in rows]


@router.post("/tokens/{token_id}/revoke", response_model=TokenOut)
def revoke(token_id: TokenId, request: Request, session: DB, user: Caller) -> TokenOut:
    """Revoke a token for good (yours; super-users: anyone's). Requests with it are refused from now on, and
    the web sessions opened with it end (other server processes refuse it within ``token_cache_seconds``).
    Revoking a revoked token changes nothing."""
    row = session.get(ApiToken, token_id)
    if row is None:
        raise ServiceError(404, f"no token {token_id}")
    if row.user_id != user.id and user.role != "superuser":
        raise ServiceError(403, f"token {token_id} belongs to another user")
    revoke_token(session, row, request.app.state.tokens)
    owner = session.get(User, row.user_id)
    return _token_view(row, owner.name if owner else "?")
