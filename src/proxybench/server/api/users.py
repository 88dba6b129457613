"""Users and tokens: super-users create accounts; everyone can see who they are and mint own tokens."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends
from sqlalchemy import select

from proxybench.server.api.deps import DB, Caller, require
from proxybench.server.api.schemas import TokenCreate, UserCreate
from proxybench.server.errors import ServiceError
from proxybench.server.models import User
from proxybench.server.security import create_user, issue_token

router = APIRouter(tags=["users"])
Superuser = Annotated[User, Depends(require())]


def _user_view(u: User) -> dict[str, Any]:
    return {"name": u.name, "role": u.role, "daily_limit": u.daily_limit, "created_at": u.created_at}


@router.get("/me")
def me(user: Caller) -> dict[str, Any]:
    """Who this token belongs to."""
    return _user_view(user)


@router.post("/users", status_code=201)
def add_user(body: UserCreate, session: DB, _: Superuser) -> dict[str, Any]:
    """Create a user (super-users only). The token in the reply is shown once."""
    try:
        user, token = create_user(session, body.name, body.role, body.daily_limit)
    except ValueError as exc:
        raise ServiceError(409 if "exists" in str(exc) else 422, str(exc)) from None
    return {**_user_view(user), "token": token}


@router.get("/users")
def list_users(session: DB, _: Superuser) -> list[dict[str, Any]]:
    return [_user_view(u) for u in session.scalars(select(User).order_by(User.id))]


@router.post("/me/tokens", status_code=201)
def new_token(body: TokenCreate, session: DB, user: Caller) -> dict[str, str]:
    """Another token for the caller (e.g. one per machine). Shown once."""
    return {"token": issue_token(session, user, body.label)}
