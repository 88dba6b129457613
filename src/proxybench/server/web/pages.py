"""Pages about benchmarks: the overview, signing in and out, benchmarks with their paths, leaderboards."""

from __future__ import annotations

import time
from typing import Annotated, Any

from fastapi import APIRouter, Form, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from proxybench.server.api.benchmarks import get_benchmark, get_leaderboard, list_benchmarks, list_paths
from proxybench.server.api.deps import DB, TOKEN_COOKIE, Caller, Conf, optional_user
from proxybench.server.api.jobs import list_evaluators
from proxybench.server.benchmarks import parse_benchmark
from proxybench.server.errors import ServiceError
from proxybench.server.leaderboards import leaderboard_rows
from proxybench.server.models import JOB_STATUSES, BenchmarkVersion, Job
from proxybench.server.queue import requeue_expired
from proxybench.server.security import user_for_token
from proxybench.server.web.common import render, safe_next
from proxybench.server.web.svg import path_dag

router = APIRouter(include_in_schema=False)

COOKIE_MAX_AGE = 30 * 86_400  # s


def status_counts(session: Session) -> dict[str, int]:
    """Jobs per status over the whole queue (every status present, zeros included)."""
    requeue_expired(session)
    counts = {status: n for status, n in session.execute(select(Job.status, func.count()).group_by(Job.status))}
    return {s: int(counts.get(s, 0)) for s in JOB_STATUSES}


@router.get("/", response_class=HTMLResponse)
def overview(request: Request, session: DB, settings: Conf, user: Caller) -> Response:
    """Benchmarks with their leaderboard's top 3, the queue in numbers, evaluators in health."""
    boards = []
    for bench in list_benchmarks(session, user):
        board = leaderboard_rows(session, bench["name"], "public")
        boards.append({**bench, "criteria": board["criteria"], "top": board["rows"][:3],
                       "entries": len(board["rows"])})
    evaluators = list_evaluators(session, settings, user)
    return render(request, "overview.html", user, boards=boards, counts=status_counts(session),
                  evaluators=evaluators, healthy=sum(e["healthy"] for e in evaluators))


@router.get("/login", response_class=HTMLResponse)
def login_form(request: Request, session: DB, next: str = "/") -> Response:
    return render(request, "login.html", optional_user(request, session), next=safe_next(next), error=None)


@router.post("/login", response_class=HTMLResponse)
def login(request: Request, session: DB, token: Annotated[str, Form()],
          next: Annotated[str, Form()] = "/") -> Response:
    """Check the pasted API token and keep it in an HttpOnly, SameSite=Strict cookie."""
    token = token.strip()
    user = user_for_token(session, token) if token else None
    if user is None:
        return render(request, "login.html", None, status_code=401, next=safe_next(next),
                      error="That token is unknown or revoked. Paste the whole token (it starts with 'pbt_').")
    response = RedirectResponse(safe_next(next), status_code=303)
    response.set_cookie(TOKEN_COOKIE, token, max_age=COOKIE_MAX_AGE, path="/", httponly=True, samesite="strict",
                        secure=request.url.scheme == "https")
    return response


@router.api_route("/logout", methods=["GET", "POST"])
def logout() -> Response:
    response = RedirectResponse("/login", status_code=303)
    response.delete_cookie(TOKEN_COOKIE, path="/", httponly=True, samesite="strict")
    return response


@router.get("/benchmarks", response_class=HTMLResponse)
def benchmarks(request: Request, session: DB, user: Caller) -> Response:
    """Every benchmark (newest version) and every benchmark path, drawn."""
    paths = [{**p, "svg": path_dag(p["spec"])} for p in list_paths(session, user)]
    return render(request, "benchmarks.html", user, benchmarks=list_benchmarks(session, user), paths=paths)


def _versions(session: Session, name: str) -> list[dict[str, Any]]:
    rows = session.scalars(select(BenchmarkVersion).where(BenchmarkVersion.name == name)
                           .order_by(BenchmarkVersion.version.desc()))
    return [{"version": r.version, "created_at": r.created_at, "spec_hash": r.spec_hash} for r in rows]


@router.get("/benchmarks/{name}", response_class=HTMLResponse)
def benchmark(request: Request, name: str, session: DB, user: Caller, version: int | None = None) -> Response:
    """One benchmark version: what it runs and how it scores, its versions, the paths it is a step of."""
    view = get_benchmark(name, session, user, version)
    spec = parse_benchmark(view["spec_yaml"], origin=f"{name} v{view['version']}")
    paths = [{**p, "svg": path_dag(p["spec"], highlight=name)} for p in list_paths(session, user)
             if any(s["benchmark"] == name for s in p["spec"]["steps"])]
    return render(request, "benchmark.html", user, b=view, spec=spec, criteria=spec.criteria(),
                  episodes=spec.episode_specs(), versions=_versions(session, name), paths=paths)


@router.get("/leaderboards/{name}", response_class=HTMLResponse)
def leaderboard(request: Request, name: str, session: DB, user: Caller, split: str = "public",
                version: int | None = None) -> Response:
    """The ranked table (semiorder; Copeland score); the hidden-split tab for super-users only."""
    if split not in ("public", "hidden"):
        raise ServiceError(422, f"split must be 'public' or 'hidden', got {split!r}")
    board = get_leaderboard(name, session, user, split, version)
    view = get_benchmark(name, session, user, board["version"])
    return render(request, "leaderboard.html", user, board=board, b=view, versions=_versions(session, name),
                  generated=time.time())
