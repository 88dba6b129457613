"""Pages about work: submissions and their results, the job queue, evaluators, and the operator view."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Form, Query, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from pydantic import ValidationError
from sqlalchemy import select

from proxybench.server.api.deps import DB, Conf, WebCaller, WebFormCaller
from proxybench.server.api.jobs import JobId, list_evaluators, list_jobs, retry_job
from proxybench.server.api.schemas import UserCreate
from proxybench.server.api.submissions import SubmissionId, get_submission, list_submissions, retire
from proxybench.server.api.users import add_user, list_users
from proxybench.server.artifacts import ArtifactStore
from proxybench.server.benchmarks import benchmark_of
from proxybench.server.errors import ServiceError
from proxybench.server.models import JOB_STATUSES, ROLES, Artifact, BenchmarkVersion, User
from proxybench.server.views import job_events
from proxybench.server.web.common import episode_table, render, user_names
from proxybench.server.web.pages import status_counts
from proxybench.server.web.scores import (
    EPISODE_NAN,
    NOT_REPORTED,
    episode_counts,
    metric_column,
    score_rows,
    value_cell,
)
from proxybench.server.web.svg import episode_bars

router = APIRouter(include_in_schema=False)


def _superuser(user: WebCaller) -> User:
    if user.role != "superuser":
        raise ServiceError(403, f"user {user.name!r} ({user.role}) may not do this; needs role superuser")
    return user


def _superuser_form(user: WebFormCaller) -> User:
    return _superuser(user)


Superuser = Annotated[User, Depends(_superuser)]
SuperuserForm = Annotated[User, Depends(_superuser_form)]

#: statuses an operator can retry (server.queue.retry)
RETRYABLE = ("error", "host-error", "timeout", "failed", "aborted")
_TEXT_PREVIEW_BYTES = 64 * 1024
_TEXT_SUFFIXES = (".log", ".txt", ".json", ".yaml", ".yml", ".csv")


@router.get("/submissions", response_class=HTMLResponse)
def submissions(request: Request, session: DB, user: WebCaller, mine: bool = False) -> Response:
    """Your submissions; super-users see everyone's (``?mine=true``: their own)."""
    return render(request, "submissions.html", user, subs=list_submissions(session, user, mine), mine=mine)


def _artifacts(session: DB, store: ArtifactStore, refs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Artifact links with media type, size, and the text of small logs (to show inline)."""
    out = []
    for ref in refs:
        row = session.get(Artifact, ref["sha256"])
        media = row.media_type if row is not None else "application/octet-stream"
        size = row.size if row is not None else None
        text = None
        is_text = media.startswith("text/") or ref["name"].lower().endswith(_TEXT_SUFFIXES)
        if is_text and size is not None and size <= _TEXT_PREVIEW_BYTES and store.has(ref["sha256"]):
            text = store.path(ref["sha256"]).read_bytes().decode("utf-8", errors="replace")
        kind = "video" if media == "video/mp4" else "image" if media.startswith("image/") else "file"
        out.append({**ref, "media_type": media, "size": size, "kind": kind, "text": text,
                    "url": f"/api/v1/artifacts/{ref['sha256']}"})
    return out


def _report(scores: dict[str, Any], report: dict[str, Any], criteria: list[Any]) -> dict[str, Any]:
    """One split of a result for the page: scores (criteria first), per-episode table and plot, failures and
    data problems."""
    metrics, rows = episode_table(report)
    columns = [metric_column(m) for m in metrics]
    for row in rows:
        row["cells"] = [value_cell(row["values"].get(c.name), c, EPISODE_NAN if c.name in row["values"] else
                                   NOT_REPORTED) for c in columns]
    failures = [f for f in report.get("agent_failures") or [] if isinstance(f, dict)]
    problems = [str(p) for p in report.get("data_problems") or []]
    return {"scores": score_rows(scores, criteria, episode_counts(metrics, rows)), "columns": columns,
            "rows": rows, "plot": episode_bars(metrics, rows, titles=[c.title for c in columns]),
            "ended": any(r["termination"] for r in rows), "failures": failures, "problems": problems}


def _criteria(session: DB, job: dict[str, Any] | None, cache: dict[tuple[str, int], list]) -> list:
    """The ranking criteria of the benchmark version a job ran (none when unknown)."""
    if job is None:
        return []
    key = (job["benchmark"], job["benchmark_version"])
    if key not in cache:
        row = session.scalar(select(BenchmarkVersion).where(BenchmarkVersion.name == key[0],
                                                            BenchmarkVersion.version == key[1]))
        try:
            cache[key] = benchmark_of(row).criteria() if row is not None else []
        except (ServiceError, ValueError):  # a benchmark that no longer parses: show the scores unranked
            cache[key] = []
    return cache[key]


@router.get("/submissions/{sid}", response_class=HTMLResponse)
def submission(request: Request, sid: SubmissionId, session: DB, user: WebCaller) -> Response:
    """Jobs with statuses and history, each result's scores, per-episode metrics and plot, artifacts."""
    sub = get_submission(sid, session, user)
    store = request.app.state.store
    jobs = {j["id"]: {**j, "events": job_events(session, j["id"])} for j in sub["jobs"]}
    results = []
    criteria_of: dict[tuple[str, int], list] = {}
    for r in sub["results"]:
        job = jobs.get(r["job_id"])
        criteria = _criteria(session, job, criteria_of)
        item = {**r, "job": job, "public": _report(r["public_scores"], r["public_report"], criteria),
                "files": _artifacts(session, store, r["artifacts"])}
        if "hidden_scores" in r:  # super-users only (server.views.result_view)
            item["hidden"] = _report(r["hidden_scores"], r["hidden_report"], criteria)
        results.append(item)
    return render(request, "submission.html", user, sub=sub, jobs=list(jobs.values()), results=results,
                  can_retire=sub["status"] == "active")


@router.post("/submissions/{sid}/retire")
def retire_submission(sid: SubmissionId, session: DB, user: WebFormCaller) -> Response:
    """Withdraw a submission from the leaderboards (its results stay)."""
    retire(sid, session, user)
    return RedirectResponse(f"/submissions/{sid}", status_code=303)


@router.get("/jobs", response_class=HTMLResponse)
def jobs(request: Request, session: DB, user: WebCaller, status: str | None = None,
         limit: Annotated[int, Query(ge=1, le=1000)] = 100) -> Response:
    """The queue: counts per status (whole queue), recent jobs you may see, filtered by status."""
    if status and status not in JOB_STATUSES:
        raise ServiceError(422, f"status must be one of {', '.join(JOB_STATUSES)}, got {status!r}")
    return render(request, "jobs.html", user, counts=status_counts(session), status=status,
                  jobs=list_jobs(session, user, status or None, limit))


@router.get("/evaluators", response_class=HTMLResponse)
def evaluators(request: Request, session: DB, settings: Conf, user: WebCaller) -> Response:
    """Evaluators and their health: healthy when seen within one lease period."""
    owners = user_names(session)
    rows = [{**e, "owner": owners.get(e["owner_id"], "?")} for e in list_evaluators(session, settings, user)]
    return render(request, "evaluators.html", user, evaluators=rows, lease_seconds=settings.lease_seconds)


def _operator(request: Request, session: DB, settings: Conf, user: User, *, status_code: int = 200,
              created: dict[str, Any] | None = None, error: str | None = None,
              form: dict[str, str] | None = None) -> Response:
    """The operator page: jobs needing attention, evaluators' coverage, users, the create-user form."""
    recent = list_jobs(session, user, None, 1000)
    evs = list_evaluators(session, settings, user)
    offered = [set(e["features"]) for e in evs if e["healthy"]]
    attention = []
    for j in recent:
        events = job_events(session, j["id"]) if j["status"] in RETRYABLE else []
        retried = next((e["message"] for e in events if e["kind"] == "retried"), None)
        if j["status"] in RETRYABLE and retried is None:
            attention.append({**j, "why": j["message"] or j["status"], "retry": True})
        elif j["status"] == "queued" and not any(set(j["features"]) <= f for f in offered):
            need = ", ".join(j["features"]) or "nothing"
            attention.append({**j, "why": f"needs {need}: no healthy evaluator offers all of them", "retry": False})
    retried_msg = None
    old, new = request.query_params.get("retried", ""), request.query_params.get("as", "")
    if old.isdigit() and new.isdigit():
        retried_msg = f"Job {old} was re-queued as job {new}."
    response = render(request, "operator.html", user, status_code=status_code, attention=attention,
                      users=list_users(session, user), roles=ROLES, created=created, error=error,
                      form=form or {"name": "", "role": "developer", "daily_limit": ""}, flash=retried_msg,
                      counts=status_counts(session), healthy=len(offered), evaluators=len(evs))
    if created is not None:
        response.headers["Cache-Control"] = "no-store"  # the page shows a token once
    return response


@router.get("/operator", response_class=HTMLResponse)
def operator(request: Request, session: DB, settings: Conf, user: Superuser) -> Response:
    return _operator(request, session, settings, user)


@router.post("/operator/jobs/{job_id}/retry")
def operator_retry(job_id: JobId, session: DB, settings: Conf, user: SuperuserForm) -> Response:
    """Re-queue a job that ended without success (server.queue.retry), then back to the operator page."""
    new = retry_job(job_id, session, settings, user)
    return RedirectResponse(f"/operator?retried={job_id}&as={new['id']}", status_code=303)


@router.post("/operator/users", response_class=HTMLResponse)
def operator_add_user(request: Request, session: DB, settings: Conf, user: SuperuserForm,
                      name: Annotated[str, Form()], role: Annotated[str, Form()],
                      daily_limit: Annotated[str, Form()] = "") -> Response:
    """Create a user; its first token is shown once on the page that answers."""
    form = {"name": name, "role": role, "daily_limit": daily_limit}
    if daily_limit.strip() and not daily_limit.strip().isdigit():
        return _operator(request, session, settings, user, status_code=422, form=form,
                         error=f"daily limit must be a whole number of submissions (or empty), got {daily_limit!r}")
    try:
        limit = int(daily_limit) if daily_limit.strip() else None
        created = add_user(UserCreate(name=name.strip(), role=role, daily_limit=limit), session, user)
    except ValueError as exc:  # also pydantic's ValidationError
        msg = "; ".join(e["msg"] for e in exc.errors()) if isinstance(exc, ValidationError) else str(exc)
        return _operator(request, session, settings, user, status_code=422, error=msg, form=form)
    except ServiceError as exc:
        return _operator(request, session, settings, user, status_code=exc.status, error=exc.message, form=form)
    return _operator(request, session, settings, user, created=created)
