"""The web console through a test client: every page, sign-in, visibility rules, escaping, operator actions."""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from proxybench.server.api.deps import SESSION_COOKIE
from proxybench.server.app import create_app
from proxybench.server.config import Settings
from proxybench.server.security import csrf_token
from proxybench.server.web.demo import DemoData, seed_demo

XSS = "<script>alert(1)</script>"


def tiny_mp4(tmp: Path) -> bytes:
    """A real (H.264) 8-frame video, small enough for a test."""
    from proxybench.media import VideoWriter

    with VideoWriter(tmp / "tiny.mp4", 8) as w:
        for k in range(8):
            w.append(np.full((64, 64, 3), 30 * k, dtype=np.uint8))
    return (tmp / "tiny.mp4").read_bytes()


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> tuple[TestClient, DemoData]:
    tmp = tmp_path_factory.mktemp("web")
    app = create_app(Settings(data_dir=tmp / "data"))
    client = TestClient(app)
    demo = seed_demo(client, app.state.admin_token, video=tiny_mp4(tmp))
    return client, demo


def sign_in(client: TestClient, token: str) -> str:
    """Sign in through the form (its CSRF token included); returns the session cookie."""
    client.cookies.clear()
    form = client.get("/login")
    csrf = re.search(r'name="csrf" value="([0-9a-f]+)"', form.text).group(1)
    r = client.post("/login", data={"token": token, "csrf": csrf}, follow_redirects=False)
    assert r.status_code == 303, r.text
    return client.cookies.get(SESSION_COOKIE)


_SESSIONS: dict[tuple[int, str], str] = {}


def as_user(site, who: str | None) -> TestClient:
    client, demo = site
    if who is None:
        client.cookies.clear()
        return client
    key = (id(client), who)
    if key not in _SESSIONS:
        _SESSIONS[key] = sign_in(client, demo.tokens[who])
    client.cookies.clear()
    client.cookies.set(SESSION_COOKIE, _SESSIONS[key])
    return client


def get(site, who: str | None, url: str, **kw):
    return as_user(site, who).get(url, follow_redirects=False, **kw)


def post(site, who: str, url: str, data: dict | None = None, csrf: bool = True):
    client = as_user(site, who)
    fields = {**(data or {}), **({"csrf": csrf_token(client.cookies.get(SESSION_COOKIE))} if csrf else {})}
    return client.post(url, data=fields, follow_redirects=False)


def test_every_page_renders_for_a_superuser(site):
    _, demo = site
    pages = ["/", "/benchmarks", "/benchmarks/aido_lf", "/benchmarks/aido_lf?version=1", "/leaderboards/aido_lf",
             "/leaderboards/aido_lf?split=hidden", "/leaderboards/thesis_loop", "/submissions",
             "/submissions?mine=true", f"/submissions/{demo.submissions['vision v2']}", "/jobs",
             "/jobs?status=failed", "/evaluators", "/operator", "/login"]
    for url in pages:
        r = get(site, "admin", url)
        assert r.status_code == 200, (url, r.text[:500])
        assert r.headers["content-type"].startswith("text/html")
        assert '<span class="user" data-testid="user">admin</span>' in r.text, url
    assert get(site, None, "/static/style.css").status_code == 200


def test_signed_out_visitors_go_to_the_login_page(site):
    r = get(site, None, "/jobs?status=queued")
    assert r.status_code == 303 and r.headers["location"] == "/login?next=%2Fjobs%3Fstatus%3Dqueued"
    assert get(site, None, "/login").status_code == 200
    client, demo = site
    client.cookies.clear()
    client.cookies.set(SESSION_COOKIE, "pbs_expired-or-made-up")
    assert client.get("/", follow_redirects=False).status_code == 303
    client.cookies.clear()
    client.cookies.set("proxybench_token", demo.tokens["alice"])  # the raw token is no cookie any more
    assert client.get("/", follow_redirects=False).status_code == 303
    api = get(site, None, "/api/v1/me")  # the JSON API keeps its JSON errors
    assert api.status_code == 401 and api.json()["detail"].startswith("no API token")


def test_login_opens_an_expiring_session_of_its_own_and_logout_ends_it(site):
    client, demo = site
    client.cookies.clear()
    form = client.get("/login")
    csrf = re.search(r'name="csrf" value="([0-9a-f]+)"', form.text).group(1)
    assert "proxybench_login=" in form.headers["set-cookie"]
    r = client.post("/login", data={"token": demo.tokens["alice"], "next": "/jobs"}, follow_redirects=False)
    assert r.status_code == 403 and "sign-in form" in r.text  # no CSRF token: refused
    r = client.post("/login", data={"token": demo.tokens["alice"], "next": "/jobs", "csrf": csrf},
                    follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/jobs"
    cookie = r.headers["set-cookie"]
    secret = client.cookies.get(SESSION_COOKIE)
    assert secret.startswith("pbs_") and demo.tokens["alice"] not in cookie  # the session's own secret
    assert f"{SESSION_COOKIE}=" in cookie and "HttpOnly" in cookie and "SameSite=strict" in cookie
    assert "Path=/" in cookie and "Max-Age=28800" in cookie
    assert client.get("/api/v1/me").json()["name"] == "alice"  # the API reads with it (GET only)
    r = client.post("/api/v1/me/tokens", json={"label": "x"})
    assert r.status_code == 401  # no writes through the API with a cookie
    form = client.get("/login")
    csrf = re.search(r'name="csrf" value="([0-9a-f]+)"', form.text).group(1)
    r = client.post("/login", data={"token": demo.tokens["alice"], "next": "//evil.example/x", "csrf": csrf},
                    follow_redirects=False)
    assert r.headers["location"] == "/"
    form = client.get("/login")  # each sign-in form is good for one sign-in
    csrf = re.search(r'name="csrf" value="([0-9a-f]+)"', form.text).group(1)
    r = client.post("/login", data={"token": "pbt_nope", "csrf": csrf}, follow_redirects=False)
    assert r.status_code == 401 and "unknown or revoked" in r.text
    secret = client.cookies.get(SESSION_COOKIE)
    r = client.post("/logout", data={"csrf": csrf_token(secret)}, follow_redirects=False)
    assert r.status_code == 303 and f'{SESSION_COOKIE}=""' in r.headers["set-cookie"]
    client.cookies.set(SESSION_COOKIE, secret)  # the old cookie, kept by a thief: ended on the server
    assert client.get("/", follow_redirects=False).status_code == 303


def test_developers_see_only_their_own_submissions_and_public_scores(site):
    _, demo = site
    theirs = demo.submissions["vision v2"]  # bob's
    r = get(site, "alice", f"/submissions/{theirs}")
    assert r.status_code == 403 and "belongs to another user" in r.text
    r = get(site, "alice", "/leaderboards/aido_lf?split=hidden")
    assert r.status_code == 403 and "super-users only" in r.text
    r = get(site, "alice", "/operator")
    assert r.status_code == 403 and "needs role superuser" in r.text
    board = get(site, "alice", "/leaderboards/aido_lf").text
    assert 'data-testid="tab-hidden"' not in board and f'href="/submissions/{theirs}"' not in board
    listing = get(site, "alice", "/submissions").text
    assert "vision baseline" in listing and "vision v2" not in listing
    own = get(site, "bob", f"/submissions/{theirs}").text
    assert "Validation scores" in own and "Test scores (hidden)" not in own
    assert "test/episodes.log" not in own and "hidden-episodes" not in own
    admin = get(site, "admin", f"/submissions/{theirs}").text
    assert "Test scores (hidden)" in admin and "test/episodes.log" in admin and 'data-testid="hidden-episodes"' in admin
    jobs = get(site, "alice", "/jobs").text
    bob_job = demo.jobs["failed"][0]
    assert f'id="job-{bob_job}"' not in jobs and "Operator</a>" not in jobs


def test_submission_page_shows_episodes_plot_artifacts_and_history(site):
    _, demo = site
    html = get(site, "bob", f"/submissions/{demo.submissions['vision v2']}").text
    table = html.split('data-testid="episodes"')[1].split("</table>")[0]
    assert len(re.findall(r"<tr>", table)) == 1 + 5  # header + one row per episode of aido_lf
    assert "survival_<wbr>time" in table
    assert '<svg class="bars"' in html and html.count('class="bars-bar"') == 5 * 5  # 5 metrics × 5 episodes
    assert re.search(r'<video controls preload="metadata" src="/api/v1/artifacts/[0-9a-f]{64}"', html)
    assert "evaluator.log" in html and "outcome: success" in html  # the log, shown inline
    assert "History of job" in html and "leased" in html
    failed = get(site, "bob", f"/submissions/{demo.submissions['random walk']}").text
    assert "observation has no &#39;camera&#39;" in failed and "Agent failure in episode 0: exited" in failed
    assert '<span class="end end-bad" title="agent process exited' in failed


def test_labels_and_names_are_escaped(site):
    client, demo = site
    r = client.post("/api/v1/submissions", headers={"Authorization": f"Bearer {demo.tokens['alice']}"},
                    json={"label": XSS, "agent": "vision", "benchmark": "aido_lf", "description": XSS})
    assert r.status_code == 201, r.text
    for url in ["/submissions", f"/submissions/{r.json()['id']}"]:
        html = get(site, "alice", url).text
        assert XSS not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    html = get(site, "alice", "/benchmarks/%3Cscript%3E").text
    assert "<script>" not in html.split("</head>")[1] and "&lt;script&gt;" in html
    html = get(site, "alice", '/login?next=/x"><script>alert(1)</script>').text
    assert XSS not in html


def test_jobs_page_filters_by_status(site):
    _, demo = site
    html = get(site, "admin", "/jobs?status=failed").text
    rows = re.findall(r'<tr id="job-(\d+)">', html)
    assert rows == [str(j) for j in demo.jobs["failed"]]
    r = get(site, "admin", "/jobs?status=bogus")
    assert r.status_code == 422 and "status must be one of" in r.text
    assert 'src="/static/refresh.js"' in html


def test_evaluators_page_shows_health(site):
    html = get(site, "alice", "/evaluators").text
    assert "lab-1" in html and 'class="badge b-green">healthy' in html


def test_operator_retries_a_job_and_creates_a_user(site):
    _, demo = site
    job = demo.jobs["error"][0]
    page = get(site, "admin", "/operator").text
    assert f'data-testid="retry-{job}"' in page and "no healthy evaluator" in page  # the path's target step
    r = post(site, "admin", f"/operator/jobs/{job}/retry")
    assert r.status_code == 303 and r.headers["location"].startswith(f"/operator?retried={job}&as=")
    new = int(r.headers["location"].rsplit("=", 1)[1])
    after = get(site, "admin", r.headers["location"]).text
    assert f"Job {job} was re-queued as job {new}." in after and f'data-testid="retry-{job}"' not in after
    assert f'id="job-{new}"' in get(site, "admin", "/jobs?status=queued").text
    again = post(site, "admin", f"/operator/jobs/{job}/retry")
    assert again.status_code == 409 and "already retried" in again.text
    assert post(site, "alice", f"/operator/jobs/{job}/retry").status_code == 403

    r = post(site, "admin", "/operator/users", {"name": "carol", "role": "developer", "daily_limit": "5"})
    assert r.status_code == 200 and r.headers["cache-control"] == "no-store"
    token = re.search(r"<code>(pbt_[^<]+)</code>", r.text).group(1)
    client, _ = site
    assert client.get("/api/v1/me", headers={"Authorization": f"Bearer {token}"}).json()["name"] == "carol"
    dup = post(site, "admin", "/operator/users", {"name": "carol", "role": "developer"})
    assert dup.status_code == 409 and "already exists" in dup.text and "pbt_" not in dup.text
    bad = post(site, "admin", "/operator/users", {"name": "dave", "role": "developer", "daily_limit": "many"})
    assert bad.status_code == 422 and "whole number" in bad.text


def test_retire_withdraws_an_own_submission_only(site):
    client, demo = site
    made = client.post("/api/v1/submissions", headers={"Authorization": f"Bearer {demo.tokens['bob']}"},
                       json={"label": "to retire", "agent": "vision", "benchmark": "thesis_loop"}).json()
    assert post(site, "alice", f"/submissions/{made['id']}/retire").status_code == 403
    r = post(site, "bob", f"/submissions/{made['id']}/retire")
    assert r.status_code == 303 and r.headers["location"] == f"/submissions/{made['id']}"
    html = get(site, "bob", f"/submissions/{made['id']}").text
    assert 'class="badge b-grey">retired' in html and "aborted" in html and 'action="/submissions/' not in html


def test_every_form_needs_the_sessions_csrf_token(site):
    _, demo = site
    job = demo.jobs["failed"][0]
    sub = demo.submissions["random walk"]
    forms = ((f"/operator/jobs/{job}/retry", {}), ("/operator/users", {"name": "mallory", "role": "superuser"}),
             ("/logout", {}))
    for url, data in forms:
        r = post(site, "admin", url, data, csrf=False)
        assert r.status_code == 403 and "CSRF" in r.text, url
        r = post(site, "admin", url, {**data, "csrf": "0" * 32}, csrf=False)
        assert r.status_code == 403 and "CSRF" in r.text, url
    assert post(site, "bob", f"/submissions/{sub}/retire", csrf=False).status_code == 403
    client = as_user(site, "admin")  # a right token, but the browser says another site sent the form
    r = client.post(f"/operator/jobs/{job}/retry", data={"csrf": csrf_token(client.cookies.get(SESSION_COOKIE))},
                    headers={"origin": "https://evil.example"}, follow_redirects=False)
    assert r.status_code == 403 and "evil.example" in r.text
    r = client.post(f"/operator/jobs/{job}/retry", data={"csrf": csrf_token(client.cookies.get(SESSION_COOKIE))},
                    headers={"sec-fetch-site": "cross-site"}, follow_redirects=False)
    assert r.status_code == 403 and "another site" in r.text
    page = get(site, "admin", "/operator").text
    assert f'data-testid="retry-{job}"' in page and "mallory" not in page  # nothing happened
    assert get(site, "bob", f"/submissions/{sub}").status_code == 200
    forms = re.findall(r"<form[^>]*>\s*<input type=\"hidden\" name=\"csrf\" value=\"([0-9a-f]*)\"", page)
    assert forms and set(forms) == {csrf_token(as_user(site, "admin").cookies.get(SESSION_COOKIE))}


def test_sessions_expire_and_end_with_their_token(tmp_path):
    app = create_app(Settings(data_dir=tmp_path / "data", session_seconds=1.0))
    client = TestClient(app)
    admin = {"Authorization": f"Bearer {app.state.admin_token}"}
    made = client.post("/api/v1/users", headers=admin, json={"name": "dana", "role": "developer"}).json()
    sign_in(client, made["token"])
    assert client.get("/jobs", follow_redirects=False).status_code == 200
    time.sleep(1.2)
    r = client.get("/jobs", follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"].startswith("/login")  # expired
    assert client.get("/api/v1/me").status_code == 401
    # revoking the token ends the sessions opened with it (and the token itself)
    app2 = create_app(Settings(data_dir=tmp_path / "data2"))
    c2 = TestClient(app2)
    admin2 = {"Authorization": f"Bearer {app2.state.admin_token}"}
    made = c2.post("/api/v1/users", headers=admin2, json={"name": "erin", "role": "developer"}).json()
    erin = {"Authorization": f"Bearer {made['token']}"}
    sign_in(c2, made["token"])
    assert c2.get("/submissions", follow_redirects=False).status_code == 200
    [tok] = c2.get("/api/v1/me/tokens", headers=erin).json()
    assert tok["prefix"] == made["token"][:10] and not tok["revoked"] and "token" not in tok
    r = c2.post(f"/api/v1/tokens/{tok['id']}/revoke", headers=admin2)
    assert r.status_code == 200 and r.json()["revoked"] and r.json()["revoked_at"] > 0
    assert c2.get("/submissions", follow_redirects=False).status_code == 303
    assert c2.get("/api/v1/me", headers=erin).status_code == 401
    c2.cookies.clear()
    form = c2.get("/login")
    csrf = re.search(r'name="csrf" value="([0-9a-f]+)"', form.text).group(1)
    r = c2.post("/login", data={"token": made["token"], "csrf": csrf}, follow_redirects=False)
    assert r.status_code == 401 and "revoked" in r.text
