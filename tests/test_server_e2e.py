"""The issue's "done when", end to end through the command line: `proxybench serve --evaluators 1` (SQLite,
one local evaluator process), a benchmark added and a built-in agent submitted from the CLI and waited for,
and the result on the leaderboard page with its report."""

from __future__ import annotations

import re
import subprocess
import sys

import httpx

from support.live_server import LiveServer
from support.sandbox import AGENT_USER_GROUP

pytestmark = AGENT_USER_GROUP  # `serve --evaluators 1`: its evaluator probes the sandbox as the agent user

TINY = """\
name: tiny_e2e
description: two short episodes for the end-to-end test
map: small_loop
episodes: {count: 2, seed: 5}
duration: 2.0
physics_rate: 30.0
frame_rate: 5.0
metrics: [survival_time, driven_lanedir_consec]
scoring:
  - {metric: driven_lanedir_consec_median, higher_is_better: true}
  - {metric: survival_time_median}
"""


def _cli(*args: str, server: LiveServer) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "proxybench.cli", *args, "--server", server.url,
                           "--token-file", str(server.data_dir / "admin.token")],
                          capture_output=True, text=True, timeout=300)


def test_serve_submit_wait_and_see_it_on_the_leaderboard_page(tmp_path):
    data = tmp_path / "data"
    data.mkdir()
    server = LiveServer(data, evaluators=1).start()
    try:
        bench = tmp_path / "tiny.yaml"
        bench.write_text(TINY)
        out = _cli("server", "benchmark-add", str(bench), server=server)
        assert out.returncode == 0, out.stderr
        out = _cli("submit", "pure-pursuit", "--benchmark", "tiny_e2e", "--label", "expert", "--wait",
                   "--timeout", "240", server=server)
        assert out.returncode == 0, out.stdout + out.stderr
        assert "success" in out.stdout and "expert" in out.stdout  # the job, then the leaderboard table
        with httpx.Client(base_url=server.url, timeout=30) as browser:  # signs in as a person does
            form = browser.get("/login")
            csrf = re.search(r'name="csrf" value="([0-9a-f]+)"', form.text).group(1)
            r = browser.post("/login", data={"token": server.admin_token, "csrf": csrf})
            assert r.status_code == 303
            page = browser.get("/leaderboards/tiny_e2e")
            assert page.status_code == 200 and "expert" in page.text
            board = httpx.get(f"{server.url}/api/v1/leaderboards/tiny_e2e", timeout=30,
                              headers={"Authorization": f"Bearer {server.admin_token}"}).json()
            sid = board["rows"][0]["submission_id"]
            sub_page = browser.get(f"/submissions/{sid}")
            assert sub_page.status_code == 200 and "driven_lanedir_consec" in sub_page.text  # the report's table
    finally:
        server.stop()
