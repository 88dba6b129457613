"""Pages about benchmarks: the overview, signing in and out, benchmarks with their paths, leaderboards."""

from __future__ import annotations

import hmac
import secrets
import time
from typing import Annotated, Any

from fastapi import APIRouter, Form, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from sqlalchemy import func, select
from sqlalchemy.orm import Session

from proxybench.server.api.benchmarks import Version, get_benchmark, list_benchmarks, list_paths
from proxybench.server.api.deps import DB, SESSION_COOKIE, Conf, WebCaller, WebFormCaller, check_same_origin, web_user
from proxybench.server.api.jobs import list_evaluators
from proxybench.server.benchmarks import parse_benchmark
from proxybench.server.errors import ServiceError
from proxybench.server.leaderboards import leaderboard_rows, simulation_scores
from proxybench.server.models import JOB_STATUSES, BenchmarkVersion, Job, Result
from proxybench.server.security import close_web_session, csrf_token, open_web_session, token_row
from proxybench.server.web.common import render, safe_next
from proxybench.server.web.scores import board_cells, board_columns, bt_cell, metric_column
from proxybench.server.web.svg import path_dag

router = APIRouter(include_in_schema=False)

LOGIN_COOKIE = "proxybench_login"  # the sign-in form's own CSRF secret (double-submit)
LEGACY_COOKIE = "proxybench_token"  # what older versions kept (the raw token): removed on sign-in and out


def status_counts(session: Session) -> dict[str, int]:
    """Jobs per status over the whole queue (every status present, zeros included)."""
    counts = {status: n for status, n in session.execute(select(Job.status, func.count()).group_by(Job.status))}
    return {s: int(counts.get(s, 0)) for s in JOB_STATUSES}


def result_scores(session: Session, rows: list[dict[str, Any]], split: str) -> dict[int, dict[str, Any]]:
    """The stored scores (intervals, episode counts) of the results a board's ``rows`` were ranked by, by
    result id: the board keeps only the ranked values. Read in chunks of ids (one query each)."""
    column = Result.public_scores if split == "public" else Result.hidden_scores
    ids = [r["result_id"] for r in rows]
    out: dict[int, dict[str, Any]] = {}
    for start in range(0, len(ids), 500):
        out.update({rid: scores or {} for rid, scores in session.execute(
            select(Result.id, column).where(Result.id.in_(ids[start:start + 500])))})
    return out


def ranked_rows(session: Session, board: dict[str, Any], rows: list[dict[str, Any]]) -> tuple[list, list]:
    """(criterion columns, rows with their cells: value, interval, episode count) for a leaderboard table."""
    columns = board_columns(board["criteria"])
    details = result_scores(session, rows, board["split"])
    bt = board.get("bt") or {}
    out = []
    for r in rows:
        full = details.get(r["result_id"], {})
        episodes = full.get("episodes")
        out.append({**r, "cells": board_cells(r["scores"], columns, full),
                    "bt": bt_cell(r.get("bt"), r["submission_id"] == bt.get("leader"), bool(bt.get("provisional"))),
                    "episodes": int(episodes) if isinstance(episodes, int | float) and episodes == episodes else None})
    return columns, out


@router.get("/", response_class=HTMLResponse)
def overview(request: Request, session: DB, settings: Conf, user: WebCaller) -> Response:
    """Benchmarks with their leaderboard's top 3, the queue in numbers, evaluators in health."""
    boards = []
    for bench in list_benchmarks(session, user):
        board = leaderboard_rows(session, bench["name"], "public", boards=request.app.state.boards)
        columns, top = ranked_rows(session, board, board["rows"][:3])
        boards.append({**bench, "columns": columns, "top": top, "entries": len(board["rows"])})
    evaluators = list_evaluators(session, settings, user)
    return render(request, "overview.html", user, boards=boards, counts=status_counts(session),
                  evaluators=evaluators, healthy=sum(e["healthy"] for e in evaluators))


@router.get("/login", response_class=HTMLResponse)
def login_form(request: Request, session: DB, next: str = "/") -> Response:
    """The sign-in form; its CSRF token is bound to a cookie of its own (no session exists yet)."""
    secret = request.cookies.get(LOGIN_COOKIE) or secrets.token_urlsafe(24)
    response = render(request, "login.html", web_user(request, session), next=safe_next(next), error=None,
                      csrf=csrf_token(secret))
    response.set_cookie(LOGIN_COOKIE, secret, max_age=3600, path="/login", httponly=True, samesite="strict",
                        secure=request.url.scheme == "https")
    return response


@router.post("/login", response_class=HTMLResponse)
def login(request: Request, session: DB, settings: Conf, token: Annotated[str, Form(max_length=200)],
          csrf: Annotated[str, Form(max_length=100)] = "",
          next: Annotated[str, Form(max_length=2000)] = "/") -> Response:
    """Check the pasted API token and open a web session: the cookie holds the session's own secret
    (HttpOnly, SameSite=Strict, expiring), never the token."""
    check_same_origin(request)
    secret = request.cookies.get(LOGIN_COOKIE, "")
    if not secret or not hmac.compare_digest(csrf, csrf_token(secret)):
        raise ServiceError(403, "the sign-in form has expired or was not sent from this site; reload it and try "
                                "again")
    row = token_row(session, token.strip())
    if row is None:
        return render(request, "login.html", None, status_code=401, next=safe_next(next), csrf=csrf,
                      error="That token is unknown or revoked. Paste the whole token (it starts with 'pbt_').")
    old = request.cookies.get(SESSION_COOKIE)
    if old:
        close_web_session(session, old)
    session_secret = open_web_session(session, row, settings.session_seconds)
    response = RedirectResponse(safe_next(next), status_code=303)
    response.set_cookie(SESSION_COOKIE, session_secret, max_age=int(settings.session_seconds), path="/",
                        httponly=True, samesite="strict", secure=request.url.scheme == "https")
    response.delete_cookie(LOGIN_COOKIE, path="/login")
    response.delete_cookie(LEGACY_COOKIE, path="/")
    return response


@router.post("/logout")
def logout(request: Request, session: DB, _: WebFormCaller) -> Response:
    """End the web session (on the server, not only in this browser)."""
    close_web_session(session, request.cookies.get(SESSION_COOKIE, ""))
    response = RedirectResponse("/login", status_code=303)
    response.delete_cookie(SESSION_COOKIE, path="/", httponly=True, samesite="strict")
    response.delete_cookie(LEGACY_COOKIE, path="/")
    return response


@router.get("/benchmarks", response_class=HTMLResponse)
def benchmarks(request: Request, session: DB, user: WebCaller) -> Response:
    """Every benchmark (newest version) and every benchmark path, drawn."""
    paths = [{**p, "svg": path_dag(p["spec"])} for p in list_paths(session, user)]
    return render(request, "benchmarks.html", user, benchmarks=list_benchmarks(session, user), paths=paths)


def _versions(session: Session, name: str) -> list[dict[str, Any]]:
    rows = session.scalars(select(BenchmarkVersion).where(BenchmarkVersion.name == name)
                           .order_by(BenchmarkVersion.version.desc()))
    return [{"version": r.version, "created_at": r.created_at, "spec_hash": r.spec_hash} for r in rows]


@router.get("/benchmarks/{name}", response_class=HTMLResponse)
def benchmark(request: Request, name: str, session: DB, user: WebCaller, version: Version = None) -> Response:
    """One benchmark version: what it runs and how it scores, its versions, the paths it is a step of."""
    view = get_benchmark(name, session, user, version)
    spec = parse_benchmark(view["spec_yaml"], origin=f"{name} v{view['version']}")
    paths = [{**p, "svg": path_dag(p["spec"], highlight=name)} for p in list_paths(session, user)
             if any(s["benchmark"] == name for s in p["spec"]["steps"])]
    return render(request, "benchmark.html", user, b=view, spec=spec, criteria=board_columns(spec.criteria()),
                  metric_columns=[metric_column(n) for n in spec.metrics], episodes=spec.episode_specs(),
                  versions=_versions(session, name), paths=paths)


@router.get("/leaderboards/{name}", response_class=HTMLResponse)
def leaderboard(request: Request, name: str, session: DB, user: WebCaller, split: str = "public",
                version: Version = None) -> Response:
    """The ranked table (semiorder; Copeland score); the hidden-split tab for super-users only."""
    if split not in ("public", "hidden"):
        raise ServiceError(422, f"split must be 'public' or 'hidden', got {split!r}")
    if split == "hidden" and user.role != "superuser":
        raise ServiceError(403, "hidden (test) scores are visible to super-users only")
    board = leaderboard_rows(session, name, split, version, boards=request.app.state.boards)
    view = get_benchmark(name, session, user, board["version"])
    columns, rows = ranked_rows(session, board, board["rows"])
    sims = simulation_scores(session, board)  # beside a result measured by watchtowers: the agent's simulation
    for r in rows:
        sim = sims.get(r["submission_id"])
        r["sim"] = None if sim is None else {**sim.model_dump(), "cells": board_cells(sim.scores, columns, None)}
    return render(request, "leaderboard.html", user, board=board, columns=columns, rows=rows, b=view,
                  versions=_versions(session, name), generated=time.time(),
                  measured=any(r.get("measured_by") for r in rows))
