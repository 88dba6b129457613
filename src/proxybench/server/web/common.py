"""What every page shares: the Jinja2 environment (autoescaped), filters, rendering and error pages.

Pages call the JSON API's own route functions and ``server.views`` for their data, so a page shows
exactly what the API would show the same caller: the visibility rules live in one place.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any
from urllib.parse import quote

import jinja2
from fastapi import Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from fastapi.templating import Jinja2Templates
from markupsafe import Markup, escape
from sqlalchemy import select
from sqlalchemy.orm import Session

from proxybench import __version__
from proxybench.server.api.deps import session_secret, web_user
from proxybench.server.db import session_scope
from proxybench.server.models import User
from proxybench.server.security import csrf_token
from proxybench.server.web.scores import CI_LEVEL

__all__ = ["STATIC_DIR", "episode_table", "error_page", "fmt_ago", "fmt_num", "fmt_time", "login_redirect", "me",
           "render", "safe_next", "templates", "user_names", "wbr"]

_HERE = Path(__file__).parent
STATIC_DIR = _HERE / "static"

#: statuses as badge colours (CSS classes ``b-<colour>``)
BADGES = {"success": "green", "healthy": "green", "active": "green", "queued": "blue", "evaluating": "amber",
          "failed": "red", "error": "red", "host-error": "red", "timeout": "red", "silent": "red",
          "aborted": "grey", "retired": "grey"}


def fmt_num(x: Any) -> str:
    """A number for a table cell: ints as they are, floats with 3 decimals, missing as a dash.

    >>> fmt_num(3), fmt_num(2.5), fmt_num(None), fmt_num(float("nan")), fmt_num(12345.678)
    ('3', '2.500', '—', 'NaN', '12,345.678')
    """
    if x is None:
        return "—"
    if isinstance(x, bool):
        return "yes" if x else "no"
    if isinstance(x, int):
        return f"{x:,d}"
    if isinstance(x, float):
        if math.isnan(x):
            return "NaN"
        if x != 0 and abs(x) < 1e-3:
            return f"{x:.2e}"
        return f"{x:,.3f}"
    return str(x)


def fmt_time(t: float | None) -> str:
    """UNIX seconds as ``YYYY-MM-DD HH:MM:SS`` (UTC)."""
    return "—" if t is None else time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(t))


def fmt_ago(t: float | None, now: float | None = None) -> str:
    """How long ago, coarsely.

    >>> fmt_ago(100.0, now=160.0), fmt_ago(0.0, now=7300.0), fmt_ago(None)
    ('1 min ago', '2 h ago', 'never')
    """
    if t is None:
        return "never"
    s = (time.time() if now is None else now) - t
    if s < 0:
        return f"in {fmt_ago(0.0, now=-s).removesuffix(' ago')}"
    for unit, size in (("d", 86_400), ("h", 3_600), ("min", 60)):
        if s >= size:
            return f"{int(s // size)} {unit} ago"
    return f"{int(s)} s ago"


def wbr(text: Any) -> Markup:
    """Escaped text with line-break opportunities after underscores (long metric names in headers).

    >>> str(wbr("survival_time<b>"))
    'survival_<wbr>time&lt;b&gt;'
    """
    return Markup(str(escape(text)).replace("_", "_<wbr>"))


def _badge(status: str | None) -> str:
    return BADGES.get(status or "", "grey")


def _environment() -> jinja2.Environment:
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(_HERE / "templates"), autoescape=True,
                             undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True)
    env.filters.update(num=fmt_num, when=fmt_time, ago=fmt_ago, badge=_badge, wbr=wbr,
                       urlquote=lambda s: quote(str(s), safe=""))
    env.globals.update(version=__version__, ci_level=CI_LEVEL)
    return env


templates = Jinja2Templates(env=_environment())


def me(user: User | None) -> dict[str, str] | None:
    """The signed-in user as the navigation bar shows it."""
    return None if user is None else {"name": user.name, "role": user.role}


def page_csrf(request: Request) -> str:
    """The CSRF token every form of a signed-in page carries (derived from the session's secret)."""
    secret = session_secret(request)
    return csrf_token(secret) if secret else ""


def render(request: Request, name: str, user: User | None, status_code: int = 200, **context: Any) -> HTMLResponse:
    """A page from ``templates/<name>``; ``me`` (the signed-in user or None) and ``csrf`` (for its forms)
    are always in the context. Pages are never stored by caches: they show a user's own data."""
    context.setdefault("flash", None)
    context.setdefault("csrf", page_csrf(request))
    response = templates.TemplateResponse(request, name, {"me": me(user), "now": time.time(), **context},
                                          status_code=status_code)
    response.headers["Cache-Control"] = "no-store"
    return response


def safe_next(target: str | None) -> str:
    """A redirect target that stays on this site (a path), else ``/``.

    >>> safe_next("/jobs?status=queued"), safe_next("//evil.example/"), safe_next("https://x"), safe_next(None)
    ('/jobs?status=queued', '/', '/', '/')
    """
    if not target or not target.startswith("/") or target.startswith("//") or "\\" in target:
        return "/"
    return target


def login_redirect(request: Request) -> RedirectResponse:
    """303 to the login page, coming back here afterwards."""
    here = request.url.path + (f"?{request.url.query}" if request.url.query else "")
    return RedirectResponse(f"/login?next={quote(here, safe='')}", status_code=303)


def _caller(request: Request) -> dict[str, str] | None:
    with session_scope(request.app.state.sessions) as session:
        return me(web_user(request, session))


def error_page(request: Request, status: int, message: str) -> Response:
    """401 goes to the login page; anything else is a page that says what is wrong."""
    if status == 401:
        return login_redirect(request)
    titles = {403: "Not allowed", 404: "Not found", 409: "Conflict", 422: "Invalid request", 429: "Too many requests"}
    return templates.TemplateResponse(
        request, "error.html", {"me": _caller(request), "now": time.time(), "flash": None, "status": status,
                                "csrf": page_csrf(request), "title": titles.get(status, "Error"),
                                "message": message}, status_code=status, headers={"Cache-Control": "no-store"})


def episode_table(report: Mapping[str, Any] | None) -> tuple[list[str], list[dict[str, Any]]]:
    """Per-episode metrics of a result's report as (metric names, rows).

    Reads ``report["episodes"]``, a list as the evaluator writes it (``proxybench.evaluator.report``):
    ``{"episode": i, "seed": s, "termination": "timeout", "scores": {name: value}, ...}``; the metrics may
    also be under ``"metrics"`` or sit beside ``episode``. Each row is ``{"episode", "seed", "termination",
    "message", "values": {name: value}}``; values that are not numbers are left out.

    >>> names, rows = episode_table({"episodes": [
    ...     {"episode": 0, "seed": 7, "termination": "off_road", "scores": {"survival_time": 12.5}},
    ...     {"episode": 1, "survival_time": 60.0, "distance": 3}]})
    >>> names, rows[0]["termination"], rows[1]["values"]
    (['survival_time', 'distance'], 'off_road', {'survival_time': 60.0, 'distance': 3})
    """
    episodes = (report or {}).get("episodes")
    if not isinstance(episodes, list):
        return [], []
    names: list[str] = []
    rows = []
    for k, ep in enumerate(episodes):
        if not isinstance(ep, Mapping):
            continue
        nested = next((ep[key] for key in ("metrics", "scores") if isinstance(ep.get(key), Mapping)), None)
        values = nested if nested is not None else {key: v for key, v in ep.items() if key not in _EPISODE_FIELDS}
        values = {str(key): v for key, v in values.items()
                  if v is None or (isinstance(v, (int, float)) and not isinstance(v, bool))}
        names.extend(n for n in values if n not in names)
        rows.append({"episode": ep.get("episode", ep.get("index", k)), "seed": ep.get("seed"),
                     "termination": ep.get("termination"), "message": ep.get("message") or "", "values": values})
    return names, rows


_EPISODE_FIELDS = frozenset({"episode", "index", "seed", "termination", "duration", "message", "events"})


def user_names(session: Session) -> dict[int, str]:
    """User ids to names (to name evaluators' owners)."""
    return {uid: name for uid, name in session.execute(select(User.id, User.name))}
