"""The web console through a test client: every page, sign-in, visibility rules, escaping, operator actions."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from fastapi.testclient import TestClient

from proxybench.server.app import create_app
from proxybench.server.config import Settings
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


def get(site, who: str | None, url: str, **kw):
    client, demo = site
    client.cookies.clear()
    if who is not None:
        client.cookies.set("proxybench_token", demo.tokens[who])
    return client.get(url, follow_redirects=False, **kw)


def post(site, who: str, url: str, data: dict | None = None):
    client, demo = site
    client.cookies.clear()
    client.cookies.set("proxybench_token", demo.tokens[who])
    return client.post(url, data=data or {}, follow_redirects=False)


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
    client, _ = site
    client.cookies.clear()
    client.cookies.set("proxybench_token", "pbt_revoked-or-made-up")
    assert client.get("/", follow_redirects=False).status_code == 303
    api = get(site, None, "/api/v1/me")  # the JSON API keeps its JSON errors
    assert api.status_code == 401 and api.json()["detail"].startswith("no API token")


def test_login_sets_a_strict_httponly_cookie_and_logout_clears_it(site):
    client, demo = site
    client.cookies.clear()
    r = client.post("/login", data={"token": demo.tokens["alice"], "next": "/jobs"}, follow_redirects=False)
    assert r.status_code == 303 and r.headers["location"] == "/jobs"
    cookie = r.headers["set-cookie"]
    assert cookie.startswith("proxybench_token=") and "HttpOnly" in cookie and "SameSite=strict" in cookie
    assert "Path=/" in cookie
    r = client.post("/login", data={"token": demo.tokens["alice"], "next": "//evil.example/x"},
                    follow_redirects=False)
    assert r.headers["location"] == "/"
    r = client.post("/login", data={"token": "pbt_nope"}, follow_redirects=False)
    assert r.status_code == 401 and "unknown or revoked" in r.text
    r = client.post("/logout", follow_redirects=False)
    assert r.status_code == 303 and 'proxybench_token=""' in r.headers["set-cookie"]


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
