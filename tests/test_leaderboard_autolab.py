"""The leaderboard marks results an Autolab's watchtowers measured, with the same agent's simulation score beside
them (issue 36 item 2): through the API as an evaluator uploads them, read back from the board and the web page."""

from __future__ import annotations

import re

import pytest
from fastapi.testclient import TestClient

from proxybench.server.app import create_app
from proxybench.server.config import Settings

SCORING = """\
map: loop_3x3
episodes: {count: 1, seed: 3}
duration: 3.0
metrics: [survival_time, driven_lanedir_consec, deviation_center_line]
scoring:
  - {metric: driven_lanedir_consec_median, higher_is_better: true}
  - {metric: survival_time_median}
"""
LAB_BENCH = "name: lab_tiny\ndescription: one short episode in a simulated Autolab\n" + SCORING
SIM_BENCH = "name: sim_tiny\ndescription: the same episode in the simulator\n" + SCORING


def _report(kind: str, lanedir: float, **extra) -> dict:
    return {"domain_kind": kind, "episodes": [{"episode": 0, "seed": 3, "scores": {"driven_lanedir_consec": lanedir,
                                                                                   "survival_time": 3.0}}], **extra}


def seed_lab_board(client: TestClient, admin_token: str) -> dict[str, str]:
    """An Autolab benchmark (lab_tiny) and a simulation one with the same criteria (sim_tiny), results uploaded as
    evaluators upload them; the users' tokens:

    - gina's pid: simulation 0.912 on sim_tiny, 0.734 measured by the watchtowers of lab 'test-lab';
    - hank's pid: 0.501 measured by watchtowers (hank has no simulation result; gina's pid is not his);
    - ivy's vision: 0.305 with no ``measured_by`` (an evaluator that does not say): not marked."""
    admin = {"Authorization": f"Bearer {admin_token}"}
    for text, feats in ((LAB_BENCH, ["autolab"]), (SIM_BENCH, ["sim"])):
        assert client.post("/api/v1/benchmarks", headers=admin, json={"yaml": text, "features": feats}).status_code \
            in (200, 201)
    tokens = {n: client.post("/api/v1/users", headers=admin, json={"name": n, "role": r}).json()["token"]
              for n, r in (("gina", "developer"), ("hank", "developer"), ("ivy", "developer"), ("lab", "evaluator"))}
    plan = [("gina", "gina pid sim", "pid", "sim_tiny", _report("simulation", 0.912)),
            ("gina", "gina pid lab", "pid", "lab_tiny",
             _report("autolab/virtual", 0.734, measured_by="watchtowers", lab="test-lab", watchtowers=12)),
            ("hank", "hank pid lab", "pid", "lab_tiny",
             _report("autolab/virtual", 0.501, measured_by="watchtowers", lab="test-lab")),
            ("ivy", "ivy vision lab", "vision", "lab_tiny", _report("autolab/virtual", 0.305))]
    for user, label, agent, bench, report in plan:
        r = client.post("/api/v1/submissions", headers={"Authorization": f"Bearer {tokens[user]}"},
                        json={"label": label, "agent": agent, "benchmark": bench})
        assert r.status_code == 201, r.text
        # an Autolab evaluator offers sim and autolab (`evaluator --autolab`)
        _upload(client, tokens, label, ["sim"] if bench == "sim_tiny" else ["sim", "autolab"], report)
    return tokens


@pytest.fixture()
def lab_site(tmp_path):
    app = create_app(Settings(data_dir=tmp_path / "data"))
    client = TestClient(app)
    return client, seed_lab_board(client, app.state.admin_token)


def _rows(html: str) -> dict[str, str]:
    """Each leaderboard row's text (tags stripped) by its submission label."""
    body = html.split('data-testid="leaderboard"', 1)[1].split("</table>", 1)[0]
    out = {}
    for row in re.findall(r"<tr>(.*?)</tr>", body.split("<tbody>", 1)[1], re.S):
        text = re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", row)).strip()
        out[text.split(" ")[1] + " " + text.split(" ")[2] + " " + text.split(" ")[3]] = text
    return out


def test_the_board_marks_what_the_watchtowers_measured(lab_site):
    client, tokens = lab_site
    board = client.get("/api/v1/leaderboards/lab_tiny", headers={"Authorization": f"Bearer {tokens['ivy']}"}).json()
    marks = {r["label"]: (r["measured_by"], r["lab"]) for r in board["rows"]}
    assert marks == {"gina pid lab": ("watchtowers", "test-lab"), "hank pid lab": ("watchtowers", "test-lab"),
                     "ivy vision lab": (None, None)}
    sim = client.get("/api/v1/leaderboards/sim_tiny", headers={"Authorization": f"Bearer {tokens['ivy']}"}).json()
    assert [r["measured_by"] for r in sim["rows"]] == [None]


def test_the_web_leaderboard_shows_the_mark_and_the_agents_simulation_score(lab_site):
    client, tokens = lab_site
    r = client.post("/login", data={"token": tokens["ivy"], "csrf": _csrf(client)}, follow_redirects=False)
    assert r.status_code == 303
    html = client.get("/leaderboards/lab_tiny").text
    assert 'data-testid="measured-head"' in html and html.count('data-testid="measured-by"') == 2
    rows = _rows(html)
    gina, hank, ivy = rows["gina pid lab"], rows["hank pid lab"], rows["ivy vision lab"]
    assert "measured by watchtowers test-lab" in gina and "simulation ( sim_tiny ): 0.91 · 3.0 0.73" in gina
    assert "measured by watchtowers" in hank and "no simulation result of this agent" in hank  # not gina's pid
    assert "measured by" not in ivy and "simulation" not in ivy
    assert 'href="/leaderboards/sim_tiny?version=1"' in html
    plain = client.get("/leaderboards/sim_tiny").text  # a board with nothing measured has no such column
    assert 'data-testid="measured-head"' not in plain and 'data-testid="measured-by"' not in plain


def _csrf(client: TestClient) -> str:
    form = client.get("/login")
    return re.search(r'name="csrf" value="([0-9a-f]+)"', form.text).group(1)


def _upload(client: TestClient, tokens: dict[str, str], label: str, feats: list[str], report: dict) -> None:
    """Lease the next job (it must be ``label``'s) and upload a success with ``report``."""
    ev = {"Authorization": f"Bearer {tokens['lab']}"}
    job = client.post("/api/v1/jobs/lease", headers=ev, json={"evaluator": "lab", "features": feats}).json()
    assert job["submission"]["label"] == label
    lanedir = report["episodes"][0]["scores"]["driven_lanedir_consec"]
    scores = {"episodes": 1, "driven_lanedir_consec_median": lanedir, "survival_time_median": 3.0}
    r = client.post(f"/api/v1/jobs/{job['job_id']}/result", headers=ev,
                    json={"lease_id": job["lease_id"], "evaluator": "lab", "status": "success", "public_scores": scores,
                          "public_report": report, "hidden_scores": scores, "hidden_report": report})
    assert r.status_code in (200, 201), r.text


def test_a_submission_run_in_simulation_then_in_the_lab_shows_its_own_simulation_score(lab_site):
    """A path (simulation, then the lab): its row shows that submission's own simulation result even when another
    submission of the same agent has a newer one, which the other rows of that agent show."""
    client, tokens = lab_site
    admin = {"Authorization": f"Bearer {client.app.state.admin_token}"}
    path = {"steps": [{"id": "sim", "benchmark": "sim_tiny"}, {"id": "lab", "benchmark": "lab_tiny"}],
            "edges": [{"source": "sim", "target": "lab", "condition": {"metric": "survival_time_median", "min": 1}}]}
    assert client.post("/api/v1/paths", headers=admin, json={"name": "sim-then-lab", "spec": path}).status_code == 201
    gina = {"Authorization": f"Bearer {tokens['gina']}"}
    r = client.post("/api/v1/submissions", headers=gina,
                    json={"label": "gina pid path", "agent": "pid", "path": "sim-then-lab"})
    assert r.status_code == 201, r.text
    _upload(client, tokens, "gina pid path", ["sim"], _report("simulation", 0.655))
    _upload(client, tokens, "gina pid path", ["sim", "autolab"],
            _report("autolab/virtual", 0.8, measured_by="watchtowers", lab="test-lab"))
    r = client.post("/api/v1/submissions", headers=gina, json={"label": "gina pid sim2", "agent": "pid",
                                                               "benchmark": "sim_tiny"})
    assert r.status_code == 201, r.text
    _upload(client, tokens, "gina pid sim2", ["sim"], _report("simulation", 0.951))  # the newest of pid
    assert client.post("/login", data={"token": tokens["gina"], "csrf": _csrf(client)},
                       follow_redirects=False).status_code == 303
    rows = _rows(client.get("/leaderboards/lab_tiny").text)
    assert "simulation ( sim_tiny ): 0.66 · 3.0" in rows["gina pid path"]  # its own, not the newest of pid
    assert "simulation ( sim_tiny ): 0.95 · 3.0" in rows["gina pid lab"]  # the newest of another submission
