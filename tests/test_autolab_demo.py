"""`proxybench autolab demo` (issue 36 item 5): one command stands up server, lab, evaluator and a submission.

Run as a process, as a user runs it: a short episode (3 s, camera and watchtowers at 5 Hz) so that the job takes
seconds of CPU besides the SDK's start.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

from support.dtps import sdk
from support.sandbox import AGENT_USER_GROUP, processes_left, require_safe_sandbox

pytestmark = AGENT_USER_GROUP

SHORT = ["--seconds", "3", "--frame-rate", "5", "--watchtower-rate", "5", "--no-video"]


def _as_from_a_terminal() -> None:
    """Ctrl-C's default action in the child, as a terminal gives it: a suite started in the background (``cmd &``,
    nohup) inherits SIGINT ignored, and Python then never raises KeyboardInterrupt, so the Ctrl-C test hung."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def demo(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "proxybench", "autolab", "demo", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env={**os.environ, "COLUMNS": "200"}, preexec_fn=_as_from_a_terminal)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


@sdk
def test_demo_once_runs_one_submission_end_to_end_and_writes_job_json(tmp_path: Path) -> None:
    require_safe_sandbox()
    out = tmp_path / "demo"
    proc = demo("--once", "--out", str(out), *SHORT)
    text, _ = proc.communicate(timeout=600)  # a guard against a hang, not a speed limit
    assert proc.returncode == 0, text
    job = json.loads((out / "job.json").read_text())
    assert job["status"] == "success", job
    assert job["measured_by"] == "watchtowers" and "measured by its watchtowers" in job["message"]
    assert job["localization_median_error_m"] <= 0.02
    assert job["scores"]["survival_time_median"] == 3.0 and job["scores"]["driven_lanedir_consec_median"] > 0.2
    assert set(job["robot_reported_scores"]) >= {"driven_lanedir_consec_median"}
    assert re.search(r"leaderboard: http://127\.0\.0\.1:\d+/leaderboards/autolab_demo", text), text
    assert (out / "lab.yaml").is_file() and (out / "server" / "admin.token").is_file()
    # two virtual robots: the evaluator runs a job on each at once (issue 36 item 3)
    assert "up to 2 jobs at once, one on each of robots db1, db2" in (out / "evaluator.log").read_text()
    assert oct((out / "developer.token").stat().st_mode & 0o777) == "0o600"
    assert processes_left(require_safe_sandbox().uid, 10) == []


def test_demo_refuses_a_folder_that_holds_something(tmp_path: Path) -> None:
    (tmp_path / "mine.txt").write_text("keep me")
    proc = demo("--once", "--out", str(tmp_path), "--dev-unsafe-same-user", *SHORT)
    text, _ = proc.communicate(timeout=300)
    assert proc.returncode == 1 and "not an empty folder" in text, text
    assert [p.name for p in tmp_path.iterdir()] == ["mine.txt"]


@sdk
def test_ctrl_c_stops_everything_the_demo_started(tmp_path: Path) -> None:
    require_safe_sandbox()
    out = tmp_path / "demo"
    proc = demo("--out", str(out), *SHORT)
    lines: list[str] = []
    evaluator = None
    assert proc.stdout is not None
    deadline = time.monotonic() + 300  # a guard against a hang, not a speed limit
    for line in proc.stdout:
        lines.append(line)
        found = re.search(r"Autolab evaluator started \(pid (\d+)", line)
        evaluator = int(found.group(1)) if found else evaluator
        if re.search(r"job \d+: evaluating", line) or time.monotonic() > deadline:
            break
    assert evaluator is not None and any("evaluating" in s for s in lines), "".join(lines)
    port = int(re.search(r"server http://127\.0\.0\.1:(\d+)", "".join(lines)).group(1))
    proc.send_signal(signal.SIGINT)
    rest, _ = proc.communicate(timeout=300)  # a guard against a hang, not a speed limit
    assert proc.returncode == 0, "".join(lines) + rest
    assert "stopped: the evaluator, its job and the server" in rest
    assert not _alive(evaluator)
    assert processes_left(require_safe_sandbox().uid, 10) == []
    import socket

    with socket.socket() as s, pytest.raises(ConnectionRefusedError):
        s.connect(("127.0.0.1", port))
