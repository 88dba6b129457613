"""The web console in a real headless Chromium (Debian's ``chromium``, driven by Playwright; no browser download).

A uvicorn server on 127.0.0.1 serves a demo database (``proxybench.server.web.demo``); the browser signs in
by pasting tokens, as people do. Skipped when ``/usr/bin/chromium`` or the ``playwright`` package is missing
(Debian: ``apt-get install chromium``; ``pip install playwright``; never ``playwright install``).
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

CHROMIUM = Path("/usr/bin/chromium")
# The network is closed here: without these flags Chromium stalls on background connections.
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync"]

if os.environ.get("PROXYBENCH_REQUIRE_CHROMIUM"):  # CI installs both: a missing one is a failure there
    assert CHROMIUM.exists(), "PROXYBENCH_REQUIRE_CHROMIUM is set but /usr/bin/chromium is missing"
    import playwright.sync_api
if not CHROMIUM.exists():
    pytest.skip("no /usr/bin/chromium: browser tests skipped (install it: apt-get install chromium)",
                allow_module_level=True)
playwright = pytest.importorskip("playwright.sync_api", reason="the 'playwright' Python package is not installed")

from fastapi.testclient import TestClient  # noqa: E402

from proxybench.server.app import create_app  # noqa: E402
from proxybench.server.config import Settings  # noqa: E402
from proxybench.server.web.demo import DemoData, seed_demo, serve_in_thread  # noqa: E402


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """(base URL, demo data, app) of a live server on a free port."""
    app = create_app(Settings(data_dir=tmp_path_factory.mktemp("web-browser") / "data"))
    with TestClient(app) as client:
        demo = seed_demo(client, app.state.admin_token)
    with serve_in_thread(app) as url:
        yield url, demo, app


@pytest.fixture(scope="module")
def browser():
    with playwright.sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS, timeout=30_000)
        yield b
        b.close()


@pytest.fixture
def page(browser):
    context = browser.new_context(viewport={"width": 1280, "height": 900})
    context.set_default_timeout(15_000)
    yield context.new_page()
    context.close()


def sign_in(page, url: str, demo: DemoData, who: str, start: str = "/") -> None:
    """Open ``start`` signed out, land on the login form, paste the token, come back to ``start``."""
    page.goto(url + start)
    assert page.url.startswith(url + "/login?next=")
    page.fill("#token", demo.tokens[who])
    page.click("form[action='/login'] button")
    page.wait_for_url(url + start)
    assert page.inner_text("[data-testid=user]") == who


def test_sign_in_and_see_the_leaderboard_ranking(server, page):
    url, demo, app = server
    sign_in(page, url, demo, "alice", "/leaderboards/aido_lf")
    labels = page.locator("[data-testid=leaderboard] tbody tr td:nth-child(2)").all_inner_texts()
    with TestClient(app) as client:
        board = client.get("/api/v1/leaderboards/aido_lf",
                           headers={"Authorization": f"Bearer {demo.tokens['alice']}"}).json()
    assert labels == [r["label"] for r in board["rows"]] and len(labels) == 4
    ranks = page.locator("[data-testid=leaderboard] tbody tr td:nth-child(1)").all_inner_texts()
    assert ranks == [str(r["rank"]) for r in board["rows"]]
    assert page.locator("[data-testid=tab-hidden]").count() == 0  # developers get no hidden tab
    page.goto(url + "/leaderboards/aido_lf?split=hidden")
    assert "super-users only" in page.inner_text("[data-testid=error-message]")
    page.click("text=Sign out")
    page.wait_for_url(url + "/login")
    page.goto(url + "/")
    assert page.url.startswith(url + "/login")


def test_the_leaderboard_shows_bradley_terry_scores_with_intervals(server, page):
    """Beside the semiorder: each row's BT score and its 95 % interval as the API has them, the "provisional" mark
    on the leader when its interval overlaps the runner-up's, and the board's fragility."""
    url, demo, app = server
    sign_in(page, url, demo, "alice", "/leaderboards/aido_lf")
    with TestClient(app) as client:
        board = client.get("/api/v1/leaderboards/aido_lf",
                           headers={"Authorization": f"Bearer {demo.tokens['alice']}"}).json()
    bt = board["bt"]
    assert bt["episodes"] == 5 and bt["resamples"] == 200 and bt["fragility"] is not None
    head = page.locator("[data-testid=leaderboard] thead [data-testid=bt-head]")
    assert " ".join(head.inner_text().split()) == "BT score [95 % interval]"
    cells = page.locator("[data-testid=leaderboard] tbody [data-testid=bt]")
    assert cells.count() == len(board["rows"]) == 4
    for k, r in enumerate(board["rows"]):
        s = r["bt"]
        text = " ".join(cells.nth(k).inner_text().replace("provisional", "").split())
        assert text == f"{s['score']:.2f} [{s['lo']:.2f}, {s['hi']:.2f}]"
        marked = cells.nth(k).locator("[data-testid=provisional]").count() == 1
        assert marked == (bt["provisional"] and r["submission_id"] == bt["leader"])
    assert page.locator("[data-testid=leaderboard] [data-testid=provisional]").count() == int(bt["provisional"])
    summary = page.locator("[data-testid=bt-summary]")
    assert summary.is_visible() and page.inner_text("[data-testid=fragility]") == bt["fragility"]["text"]
    assert ("provisional" in summary.inner_text()) == bt["provisional"]


def test_submission_page_shows_metrics_and_plot(server, page):
    url, demo, app = server
    sid = demo.submissions["vision v2"]
    sign_in(page, url, demo, "bob", f"/submissions/{sid}")
    with TestClient(app) as client:
        sub = client.get(f"/api/v1/submissions/{sid}", headers={"Authorization": f"Bearer {demo.tokens['bob']}"})
    episodes = sub.json()["results"][0]["public_report"]["episodes"]
    heads = page.locator("[data-testid=episodes] thead th")
    header = [" ".join(h.split()) for h in heads.all_inner_texts()]
    assert header[:3] == ["episode", "seed", "ended by"] and "Survival time [s] ↑" in header
    metrics = [heads.nth(k).get_attribute("data-metric") for k in range(heads.count())]
    rows = page.locator("[data-testid=episodes] tbody tr")
    assert rows.count() == len(episodes) == 5
    for k, ep in enumerate(episodes):
        cells = rows.nth(k).locator("td").all_inner_texts()
        assert cells[:3] == [str(ep["episode"]), str(ep["seed"]), ep["termination"]]
        assert cells[metrics.index("survival_time")] == f"{ep['scores']['survival_time']:,.1f}"  # [s]: 0.1 s
        assert cells[metrics.index("deviation_center_line")] == f"{ep['scores']['deviation_center_line']:,.3f}"
    scores = page.locator("[data-testid=scores] tbody tr.criterion")
    assert scores.count() == 4 and scores.nth(0).locator("th").inner_text().startswith("Distance along the lane")
    assert scores.nth(0).locator("td.ci").inner_text().startswith("[")  # the statistic's interval, beside it
    plot = page.locator("svg.bars")
    assert plot.is_visible() and plot.bounding_box()["width"] > 300
    assert page.locator("svg.bars rect.bars-bar").count() == 25
    assert page.locator("text=Test scores (hidden)").count() == 0
    page.click("text=History of job")
    assert page.locator("details.log pre").first.is_visible()


def test_a_developer_cannot_open_another_users_submission(server, page):
    url, demo, _ = server
    sign_in(page, url, demo, "alice")
    response = page.goto(url + f"/submissions/{demo.submissions['vision v2']}")
    assert response.status == 403
    assert page.inner_text("h1") == "403 · Not allowed"
    assert "belongs to another user" in page.inner_text("[data-testid=error-message]")
    assert page.goto(url + "/operator").status == 403
    assert page.locator("nav >> text=Operator").count() == 0


def test_operator_retry_requeues_a_failed_job(server, page):
    url, demo, _ = server
    job = demo.jobs["failed"][0]
    sign_in(page, url, demo, "admin", "/operator")
    page.click(f"[data-testid=retry-{job}]")
    page.wait_for_url(re.compile(r".*/operator\?retried=\d+&as=\d+$"))
    new = page.url.rsplit("=", 1)[1]
    assert page.inner_text(".flash") == f"Job {job} was re-queued as job {new}."
    assert page.locator(f"[data-testid=retry-{job}]").count() == 0
    page.goto(url + "/jobs?status=queued")
    row = page.locator(f"#job-{new}")
    assert row.is_visible() and "queued" in row.inner_text()



def test_a_form_on_another_site_cannot_act_for_a_signed_in_user(server, page, tmp_path):
    """Another origin (here another port of 127.0.0.1: the same *site*, so SameSite=Strict still sends the
    cookie) auto-submits the operator's Retry form: refused (no CSRF token, foreign Origin), nothing retried."""
    import http.server
    import threading

    url, demo, _ = server
    job = demo.jobs["failed"][1] if len(demo.jobs["failed"]) > 1 else demo.jobs["error"][0]
    (tmp_path / "evil.html").write_text(
        f'<form id="f" method="post" action="{url}/operator/jobs/{job}/retry"><input name="csrf" value="guess">'
        '</form><script>document.getElementById("f").submit()</script>')
    handler = lambda *a: http.server.SimpleHTTPRequestHandler(*a, directory=str(tmp_path))  # noqa: E731
    evil = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    threading.Thread(target=evil.serve_forever, daemon=True).start()
    try:
        sign_in(page, url, demo, "admin", "/operator")
        assert page.locator(f"[data-testid=retry-{job}]").count() == 1
        with page.expect_response(lambda r: "/retry" in r.url) as answer:
            page.goto(f"http://127.0.0.1:{evil.server_address[1]}/evil.html")
        assert answer.value.status == 403
        assert "another site" in page.inner_text("[data-testid=error-message]") or \
            "not from this site" in page.inner_text("[data-testid=error-message]")
        page.goto(url + "/operator")
        assert page.locator(f"[data-testid=retry-{job}]").count() == 1  # still not retried
    finally:
        evil.shutdown()


def test_an_expired_or_revoked_session_goes_back_to_the_login_page(server, page):
    from sqlalchemy import select, update

    from proxybench.server.models import User, WebSession

    url, demo, app = server
    with TestClient(app) as client:
        made = client.post("/api/v1/users", headers={"Authorization": f"Bearer {demo.tokens['admin']}"},
                           json={"name": "frank", "role": "developer"}).json()
    demo.tokens["frank"] = made["token"]
    sign_in(page, url, demo, "frank", "/submissions")
    with app.state.sessions() as session:  # the session's time is up
        uid = session.scalar(select(User.id).where(User.name == "frank"))
        session.execute(update(WebSession).where(WebSession.user_id == uid).values(expires_at=0.0))
        session.commit()
    page.goto(url + "/submissions")
    assert page.url.startswith(url + "/login")
    sign_in(page, url, demo, "frank", "/jobs")
    with TestClient(app) as client:
        frank = {"Authorization": f"Bearer {made['token']}"}
        [tok] = client.get("/api/v1/me/tokens", headers=frank).json()
        assert client.post(f"/api/v1/tokens/{tok['id']}/revoke", headers=frank).status_code == 200
    page.goto(url + "/jobs")
    assert page.url.startswith(url + "/login")


@pytest.fixture(scope="module")
def lab_server(tmp_path_factory):
    """(base URL, tokens) of a live server whose Autolab board holds results measured by watchtowers
    (test_leaderboard_autolab.seed_lab_board)."""
    from test_leaderboard_autolab import seed_lab_board

    app = create_app(Settings(data_dir=tmp_path_factory.mktemp("web-browser-lab") / "data"))
    with TestClient(app) as client:
        tokens = seed_lab_board(client, app.state.admin_token)
    with serve_in_thread(app) as url:
        yield url, tokens


def test_the_leaderboard_marks_results_measured_by_watchtowers(lab_server, page):
    """Issue 36: an Autolab result is marked "measured by watchtowers", the agent's simulation score beside it."""
    url, tokens = lab_server
    sign_in(page, url, DemoData(tokens=tokens), "ivy", "/leaderboards/lab_tiny")
    rows = page.locator("[data-testid=leaderboard] tbody tr")
    assert rows.count() == 3
    labels = page.locator("[data-testid=leaderboard] tbody tr td:nth-child(2)").all_inner_texts()
    assert labels == ["gina pid lab", "hank pid lab", "ivy vision lab"]  # ranked by the watchtowers' scores
    gina, hank, ivy = (rows.nth(k) for k in range(3))
    assert gina.locator("[data-testid=measured-by]").inner_text() == "measured by watchtowers"
    assert "lab test-lab" in gina.locator("[data-testid=measured-by]").get_attribute("title")
    assert gina.locator("[data-testid=sim-score]").inner_text() == "simulation (sim_tiny): 0.91 · 3.0"
    assert hank.locator("[data-testid=measured-by]").is_visible()
    assert hank.locator("[data-testid=sim-score]").inner_text() == "no simulation result of this agent"
    assert ivy.locator("[data-testid=measured-by]").count() == 0
    gina.locator("[data-testid=sim-score] a").click()  # the simulation score links to its board
    page.wait_for_url(url + "/leaderboards/sim_tiny?version=1")
    assert page.locator("[data-testid=leaderboard] tbody tr td:nth-child(2)").all_inner_texts() == ["gina pid sim"]
