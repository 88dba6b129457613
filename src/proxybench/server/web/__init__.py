"""The web console: server-rendered pages (Jinja2, autoescaped) over the same data and rules as the JSON API.

Pages: ``/`` overview, ``/login`` and ``/logout``, ``/benchmarks`` (with paths), ``/benchmarks/{name}``,
``/leaderboards/{name}``, ``/submissions`` and ``/submissions/{id}``, ``/jobs``, ``/evaluators`` and
``/operator`` (super-users). Signing in checks the API token and opens a web session of its own (an
expiring secret in an HttpOnly, SameSite=Strict cookie, never the token), which the API also accepts for
reads, so artifact links and videos load with it; every form carries the session's CSRF token. Errors
outside ``/api/`` become pages: 401 redirects to the login page, others say what is wrong.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException
from starlette.responses import Response

from proxybench.server.errors import ServiceError
from proxybench.server.web.common import STATIC_DIR, error_page

__all__ = ["mount"]

_API = "/api/"


def _html_errors(app: FastAPI, exc_class: type[Exception], message: Callable[[Any], tuple[int, str]]) -> None:
    """Answer ``exc_class`` with an error page outside the API, and as before (JSON) inside it."""
    api_handler = app.exception_handlers.get(exc_class)

    async def handler(request: Request, exc: Exception) -> Response:
        if request.url.path.startswith(_API) and api_handler is not None:
            return await api_handler(request, exc)
        status, text = message(exc)
        return await run_in_threadpool(error_page, request, status, text)  # it reads the database

    app.add_exception_handler(exc_class, handler)


def _validation_text(exc: RequestValidationError) -> tuple[int, str]:
    parts = [f"{'.'.join(str(p) for p in e.get('loc', ()))}: {e.get('msg', 'invalid')}" for e in exc.errors()[:5]]
    return 422, "; ".join(parts)


def mount(app: FastAPI) -> None:
    """Add the pages, ``/static`` and HTML error pages to ``app`` (the JSON API is left as it is)."""
    from proxybench.server.web import pages, runs

    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")
    app.include_router(pages.router)
    app.include_router(runs.router)
    _html_errors(app, ServiceError, lambda exc: (exc.status, exc.message))
    _html_errors(app, RequestValidationError, _validation_text)
    _html_errors(app, HTTPException, lambda exc: (exc.status_code, str(exc.detail)))
