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
    assert re.search(r'data-metric="survival_time"><span title="[^"]*">Survival time</span> <span class="unit">'
                     r'\[s\]</span> <span class="dir" title="higher is better">↑</span>', table)
    assert '<svg class="bars"' in html and html.count('class="bars-bar"') == 5 * 5  # 5 metrics × 5 episodes
    assert re.search(r'<video controls preload="metadata" src="/api/v1/artifacts/[0-9a-f]{64}"', html)
    assert "evaluator.log" in html and "outcome: success" in html  # the log, shown inline
    assert "History of job" in html and "leased" in html
    failed = get(site, "bob", f"/submissions/{demo.submissions['random walk']}").text
    assert "observation has no &#39;camera&#39;" in failed and "Agent failure in episode 0: exited" in failed
    assert '<span class="end end-bad" title="agent process exited' in failed


def _cells(html: str, testid: str) -> list[list[str]]:
    """The rows of a table as lists of cell texts (tags stripped)."""
    body = html.split(f'data-testid="{testid}"')[1].split("</table>")[0].split("<tbody>")[1]
    rows = re.findall(r"<tr[^>]*>(.*?)</tr>", body, flags=re.S)
    return [[re.sub(r"<[^>]+>", "", c).strip() for c in re.findall(r"<t[hd][^>]*>(.*?)</t[hd]>", r, flags=re.S)]
            for r in rows]


def test_scores_show_labels_units_criteria_first_and_intervals(site):
    """The scores table: the benchmark's criteria first, in order, with tolerance; then the other metrics;
    each with label, unit, direction, the statistic with its interval, the spread and the episode count."""
    client, demo = site
    sid = demo.submissions["vision v2"]
    html = get(site, "bob", f"/submissions/{sid}").text
    stored = client.get(f"/api/v1/submissions/{sid}", headers={"Authorization": f"Bearer {demo.tokens['bob']}"}
                        ).json()["results"][0]["public_scores"]
    order = re.findall(r'<tr class="(?:criterion|other)" data-metric="([a-z_]+)"',
                       html.split('data-testid="scores"')[1].split("</table>")[0])
    assert order == ["driven_lanedir_consec", "survival_time", "deviation_center_line", "in_drivable_lane",
                     "deviation_heading"]  # aido_lf's criteria in their order, then the one it does not rank by
    rows = [r for r in _cells(html, "scores") if len(r) == 8]
    first, d = rows[0], {k.removeprefix("driven_lanedir_consec_"): v for k, v in stored.items()}
    assert first[:4] == ["1", "Distance along the lane [m] ↑", "median", f"{d['median']:.2f}"]
    assert first[4:6] == [f"[{d['median_lo']:.2f}, {d['median_hi']:.2f}]", f"{d['min']:.2f} … {d['max']:.2f}"]
    assert first[6:] == ["5", "± 0.62"]
    assert rows[1][:4] == ["2", "Survival time [s] ↑", "median", f"{stored['survival_time_median']:.1f}"]
    assert rows[2][1:4:2] == ["Centre-line deviation [m·s] ↓", f"{stored['deviation_center_line_median']:.3f}"]
    assert rows[2][7] == "± 0.01" and rows[3][1] == "Time out of the lane [s] ↓"
    assert rows[4][0] == "" and rows[4][1] == "Heading deviation [rad·s] ↓" and rows[4][7] == ""  # not a criterion
    assert "not ranked by" in html and "95 % interval" in html
    episodes = _cells(html, "episodes")
    ep0 = client.get(f"/api/v1/submissions/{sid}", headers={"Authorization": f"Bearer {demo.tokens['bob']}"}
                     ).json()["results"][0]["public_report"]["episodes"][0]["scores"]
    assert episodes[0][3:] == [f"{ep0['survival_time']:.1f}", f"{ep0['driven_lanedir_consec']:.2f}",
                               f"{ep0['deviation_center_line']:.3f}", f"{ep0['in_drivable_lane']:.1f}",
                               f"{ep0['deviation_heading']:.2f}"]  # each unit's precision
    assert ">Survival time [s]</text>" in html  # the plot's panels carry the same labels


def test_leaderboard_and_overview_show_labels_tolerances_and_intervals_while_the_api_stays_raw(site):
    client, demo = site
    html = get(site, "alice", "/leaderboards/aido_lf").text
    heads = re.findall(r'<th class="num crit" data-metric="([a-z_]+)"', html)
    assert heads == ["driven_lanedir_consec_median", "survival_time_median", "deviation_center_line_median",
                     "in_drivable_lane_median"]
    assert re.search(r'<span class="order">1\.</span> Distance along the lane <span class="unit">\[m\]</span> '
                     r'<span class="dir" title="higher is better">↑</span><br><span class="tol">median · ± 0.62</span>',
                     html)
    api = client.get("/api/v1/leaderboards/aido_lf", headers={"Authorization": f"Bearer {demo.tokens['alice']}"}).json()
    top = api["rows"][0]
    assert set(top["scores"]) == set(heads)  # the JSON API: the ranked values only, as stored
    assert set(api["criteria"][0]) == {"metric", "higher_is_better", "tolerance"}
    stored = client.get(f"/api/v1/submissions/{top['submission_id']}",
                        headers={"Authorization": f"Bearer {demo.tokens[top['user']]}"}).json()["results"][0]
    rows = _cells(html, "leaderboard")
    lo, hi = stored["public_scores"]["driven_lanedir_consec_median_lo"], stored["public_scores"][
        "driven_lanedir_consec_median_hi"]
    assert rows[0][4] == f"{top['scores']['driven_lanedir_consec_median']:.2f}[{lo:.2f}, {hi:.2f}]"
    assert rows[0][8] == "5"  # episodes
    overview = get(site, "alice", "/").text.split('data-testid="board-aido_lf"')[1].split("</article>")[0]
    assert "Distance along the lane" in overview and "median · criterion 1 of 4" in overview
    assert f"[{lo:.2f}, {hi:.2f}]" in overview
    bench = get(site, "alice", "/benchmarks/aido_lf").text
    assert "± 0.01 m·s" in bench and "Centre-line deviation" in bench


def test_missing_values_are_a_dash_that_says_why(tmp_path):
    """A criterion the evaluator could not compute (null), a column it did not report and an episode's NaN
    are each shown as "—" with a title giving the reason; the page still ranks and renders."""
    app = create_app(Settings(data_dir=tmp_path / "data"))
    client = TestClient(app)
    admin = {"Authorization": f"Bearer {app.state.admin_token}"}
    tokens = {n: client.post("/api/v1/users", headers=admin, json={"name": n, "role": r}).json()["token"]
              for n, r in (("gina", "developer"), ("lab", "evaluator"))}
    sub = client.post("/api/v1/submissions", headers={"Authorization": f"Bearer {tokens['gina']}"},
                      json={"label": "nan case", "agent": "vision", "benchmark": "thesis_loop"}).json()
    ev = {"Authorization": f"Bearer {tokens['lab']}"}
    job = client.post("/api/v1/jobs/lease", headers=ev, json={"evaluator": "lab", "features": ["sim"]}).json()
    scores = {"episodes": 2, "distance_mean": None, "distance_n": 0, "survival_time_mean": 20.0,
              "survival_time_mean_lo": 10.0, "survival_time_mean_hi": 30.0, "survival_time_n": 2}
    report = {"episodes": [{"episode": 0, "seed": 1, "termination": "off_road",
                            "scores": {"distance": None, "survival_time": 10.0}},
                           {"episode": 1, "seed": 2, "termination": "off_road", "scores": {"survival_time": 30.0}}]}
    r = client.post(f"/api/v1/jobs/{job['job_id']}/result", headers=ev,
                    json={"lease_id": job["lease_id"], "evaluator": "lab", "status": "success",
                          "public_scores": scores, "public_report": report, "hidden_scores": scores,
                          "hidden_report": report})
    assert r.status_code in (200, 201), r.text
    site2 = (client, DemoData(tokens={"gina": tokens["gina"]}))
    html = get(site2, "gina", f"/submissions/{sub['id']}").text
    rows = _cells(html, "scores")
    assert rows[0][:4] == ["1", "Distance along the lane (thesis) [m] ↑", "mean", "—"]
    assert 'title="not computed: no episode gave a finite value (NaN); it ranks worst">—' in html
    assert 'title="no interval in this result (the evaluator reported the statistic only)">—' in html
    assert rows[1][3:5] == ["20.0", "[10.0, 30.0]"]
    assert 'title="no value in this episode (NaN): left out of the statistics over episodes">—' in html
    assert 'title="not in this result (the evaluator did not report it)">—' in html  # episode 1 has no distance
    board = get(site2, "gina", "/leaderboards/thesis_loop").text
    assert 'title="not computed: no episode gave a finite value (NaN); it ranks worst">—' in board


def test_leaderboard_shows_bradley_terry_scores_or_says_why_not(site, tmp_path, monkeypatch):
    """The BT column (score, interval, the leader's "provisional" mark) and the board's summary with its fragility;
    a board too large for Bradley–Terry, and one without per-episode reports, render with a dash and a reason."""
    client, demo = site
    html = get(site, "alice", "/leaderboards/aido_lf").text
    api = client.get("/api/v1/leaderboards/aido_lf", headers={"Authorization": f"Bearer {demo.tokens['alice']}"}).json()
    rows = _cells(html, "leaderboard")
    for cells, r in zip(rows, api["rows"], strict=True):
        shown = cells[11].removeprefix("provisional").strip()
        assert shown == f"{r['bt']['score']:.2f}[{r['bt']['lo']:.2f}, {r['bt']['hi']:.2f}]"
    assert f'data-testid="fragility">{api["bt"]["fragility"]["text"]}<' in html
    assert 'data-testid="bt-head"' in html and "BT score" in html

    from proxybench.server import leaderboards

    monkeypatch.setattr(leaderboards, "BT_MAX_AGENTS", 1)
    app = create_app(Settings(data_dir=tmp_path / "data"))
    fresh = TestClient(app)
    admin = {"Authorization": f"Bearer {app.state.admin_token}"}
    tokens = {n: fresh.post("/api/v1/users", headers=admin, json={"name": n, "role": r}).json()["token"]
              for n, r in (("gina", "developer"), ("lab", "evaluator"))}
    ev = {"Authorization": f"Bearer {tokens['lab']}"}
    for label, v in (("one", 1.0), ("two", 2.0)):
        fresh.post("/api/v1/submissions", headers={"Authorization": f"Bearer {tokens['gina']}"},
                   json={"label": label, "agent": "vision", "benchmark": "thesis_loop"})
        job = fresh.post("/api/v1/jobs/lease", headers=ev, json={"evaluator": "lab", "features": ["sim"]}).json()
        report = {"episodes": [{"episode": k, "seed": k, "scores": {"distance": v + k, "survival_time": 10.0}}
                               for k in range(3)]}
        scores = {"distance_mean": v + 1, "survival_time_mean": 10.0}
        assert fresh.post(f"/api/v1/jobs/{job['job_id']}/result", headers=ev,
                          json={"lease_id": job["lease_id"], "evaluator": "lab", "status": "success",
                                "public_scores": scores, "public_report": report,
                                "hidden_scores": scores}).status_code == 201
    site2 = (fresh, DemoData(tokens={"gina": tokens["gina"], "admin": app.state.admin_token}))
    big = get(site2, "gina", "/leaderboards/thesis_loop").text
    assert "Bradley–Terry scores are computed for boards of at most 1" in big
    assert big.count('title="no Bradley–Terry score: no per-episode report') == 2
    hidden = get(site2, "admin", "/leaderboards/thesis_loop?split=hidden").text  # no hidden reports: no summary
    assert 'data-testid="bt-summary"' not in hidden and hidden.count('data-testid="bt"') == 2


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
