"""The evaluator against a real challenges server (uvicorn in a thread, SQLite in a temp folder).

Jobs use a tiny benchmark (2 episodes of 2 s at 5 Hz) so each one takes a few seconds. The evaluator
under test is either in-process (``Evaluator.take_one``) or a ``proxybench evaluator`` subprocess.
"""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import threading
import time
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

import uvicorn

from proxybench.client import ServerClient, ServerError
from proxybench.evaluator import Evaluator, EvaluatorConfig
from support.sandbox import AGENT_USER_GROUP, processes_left, require_safe_sandbox

pytestmark = AGENT_USER_GROUP  # its agents and evaluators run as the agent user: one test at a time

TINY = """\
name: tiny_eval
description: two short episodes for the evaluator tests
map: small_loop
episodes: {count: 2, seed: 3}
duration: 2.0
physics_rate: 30.0
frame_rate: 5.0
metrics: [survival_time, driven_lanedir_consec]
scoring:
  - {metric: driven_lanedir_consec_median, higher_is_better: true}
  - {metric: survival_time_median}
"""

FORWARD_NODE = """\
import sys, time
import numpy as np
from proxybench.agents.base import Agent
from proxybench.protocol import serve

MODE = sys.argv[1] if len(sys.argv) > 1 else "ok"

class Forward(Agent):
    name = "forward"
    def reset(self, seed, episode=None):
        self.k = 0
    def act(self, obs):
        self.k += 1
        if MODE == "crash" and self.k == 3:
            sys.stderr.write("about to fail\\nZeroDivisionError: my agent divided by zero\\n")
            sys.stderr.flush()
            os._exit(3)
        if MODE == "slow":
            time.sleep(0.05)
        return np.array([0.3, 0.3])

sys.exit(serve(Forward()))
"""


MISBEHAVE = Path(__file__).with_name("protocol_agents") / "misbehave.py"


def make_package(mode: str = "ok") -> bytes:
    """A zip agent package: manifest + a python protocol node. ``ok`` / ``slow``: a proxybench-served agent
    driving forward (slowly: 0.05 s per decision); ``crash``: a bare node that dies at its first command."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        if mode == "crash":
            command, files = "[python3, misbehave.py, crash]", {"misbehave.py": MISBEHAVE.read_text()}
        else:
            command, files = f"[python3, agent.py, {mode}]", {"agent.py": FORWARD_NODE}
        zf.writestr("proxybench-agent.yaml", f"name: forward-{mode}\nprotocol: aido-z2\ncommand: {command}\n")
        for name, text in files.items():
            zf.writestr(name, text)
    return buf.getvalue()


@dataclass
class Served:
    url: str
    data_dir: Path
    admin: ServerClient
    evaluator_token: str
    developer: ServerClient


@pytest.fixture
def served(tmp_path: Path, request: pytest.FixtureRequest) -> Iterator[Served]:
    """A server with a short lease (5 s: it answers heartbeats from a thread of this process, which the
    rest of the test process can stall; with 2 s a rescuer's lease once lapsed in a clean-clone CI run), an
    evaluator user, a developer and the tiny benchmark, with a
    hidden split (``tiny_eval``) and without (``tiny_open``, for speed). SQLite unless a test asks for
    ``postgresql`` (indirect parametrisation)."""
    from proxybench.server.app import create_app
    from proxybench.server.config import Settings

    url = request.getfixturevalue("postgres").new_database() if getattr(request, "param", None) == "postgresql" \
        else None
    app = create_app(Settings(data_dir=tmp_path / "server", lease_seconds=5.0, database_url=url))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline, "server did not start"
        time.sleep(0.02)
    url = f"http://127.0.0.1:{server.servers[0].sockets[0].getsockname()[1]}"
    admin = ServerClient(url, app.state.admin_token, retry_for=5)
    ev = admin.post("/users", {"name": "ev", "role": "evaluator"})
    dev = admin.post("/users", {"name": "dev", "role": "developer"})
    admin.post("/benchmarks", {"yaml": TINY, "features": ["sim"], "test_seed": 7})
    admin.post("/benchmarks", {"yaml": TINY.replace("tiny_eval", "tiny_open"), "hidden_split": False})
    developer = ServerClient(url, dev["token"], retry_for=5)
    try:
        yield Served(url, tmp_path / "server", admin, ev["token"], developer)
    finally:
        admin.close()
        developer.close()
        server.should_exit = True
        thread.join(timeout=10)


def evaluator(served: Served, tmp_path: Path, name: str = "e1", **kw) -> Evaluator:
    cfg = EvaluatorConfig(name=name, work_dir=tmp_path / f"work-{name}", poll=0.2, post_retry_s=20, **kw)
    return Evaluator(served.url, served.evaluator_token, cfg)


def submit_archive(served: Served, tmp_path: Path, data: bytes, label: str) -> dict:
    path = tmp_path / f"{label}.zip"
    path.write_bytes(data)
    return served.developer.submit_archive(path, label, benchmark="tiny_open")


def the_job(served: Served, sub_id: int) -> tuple[dict, list[dict]]:
    sub = served.admin.get(f"/submissions/{sub_id}")
    (job,) = sub["jobs"]
    return job, sub["results"]


# -- end to end --------------------------------------------------------------------------------------

def test_builtin_agent_succeeds_and_is_ranked(served: Served, tmp_path: Path) -> None:
    sub = served.developer.submit("pid", "pid-line", benchmark="tiny_eval")
    ev = evaluator(served, tmp_path)
    posted = []
    real_result = ev.client.result

    def reply_lost_once(job_id: int, body: dict) -> dict:  # the server stores it, the reply never arrives
        posted.append(real_result(job_id, body)["recorded"])
        if len(posted) == 1:
            raise ServerError(0, "connection reset by peer")
        return {}

    ev.client.result = reply_lost_once
    assert ev.take_one() == "success"
    assert posted == [True, False]  # retried; the server recognised the repeat and stored nothing new
    assert ev.take_one() is None  # nothing left
    job, (result,) = the_job(served, sub["id"])
    assert job["status"] == "success" and job["attempts"] == 1
    scores = result["public_scores"]
    assert scores["survival_time_median"] == pytest.approx(2.0)
    assert set(result["hidden_scores"]) >= {"driven_lanedir_consec_median", "survival_time_median"}
    report = result["public_report"]
    assert report["domain_kind"] == "simulation" and [e["termination"] for e in report["episodes"]] == ["timeout"] * 2
    names = {a["name"]: a["hidden"] for a in result["artifacts"]}
    assert names["trajectories-validation.zip"] is False and names["trajectories-test.zip"] is True
    assert names["evaluator.log"] is False and names["evaluator-hidden.log"] is True
    board = served.developer.leaderboard("tiny_eval")
    assert [r["label"] for r in board["rows"]] == ["pid-line"]
    # the developer sees neither hidden scores nor hidden artifacts; the trajectories are a zip of Parquet files
    mine = served.developer.get(f"/submissions/{sub['id']}")["results"][0]
    assert "hidden_scores" not in mine and all(not a["hidden"] for a in mine["artifacts"])
    zipped = next(a for a in mine["artifacts"] if a["name"] == "trajectories-validation.zip")
    with zipfile.ZipFile(io.BytesIO(served.developer.http.get(f"/artifacts/{zipped['sha256']}").content)) as zf:
        assert sorted(zf.namelist()) == ["episode-0.parquet", "episode-1.parquet", "results.parquet"]


def test_archive_agent_runs_sandboxed_and_succeeds(served: Served, tmp_path: Path) -> None:
    require_safe_sandbox()
    sub = submit_archive(served, tmp_path, make_package("ok"), "fwd")
    ev = evaluator(served, tmp_path, video=False)
    assert ev.take_one() == "success"
    job, (result,) = the_job(served, sub["id"])
    assert job["status"] == "success", job["message"]
    assert result["public_scores"]["survival_time_median"] == pytest.approx(2.0)
    assert result["public_scores"]["driven_lanedir_consec_median"] > 0.05  # it drove forward
    sandbox = result["public_report"]["sandbox"]
    assert sandbox == ev.isolation.report() and sandbox["safe"] and sandbox["user"] == "proxybench-agent"


def test_crashing_archive_agent_fails_with_its_stderr(served: Served, tmp_path: Path) -> None:
    require_safe_sandbox()
    sub = submit_archive(served, tmp_path, make_package("crash"), "crashy")
    ev = evaluator(served, tmp_path, video=False)
    assert ev.take_one() == "failed"
    job, (result,) = the_job(served, sub["id"])
    assert job["status"] == "failed"
    msg = result["message"]
    assert "the agent failed the agent contract before its episodes: commands:" in msg  # refused before them
    assert "exited" in msg and "boom: something broke" in msg  # the node's own last words
    assert result["public_scores"] == {}
    assert {f["reason"] for f in result["public_report"]["agent_failures"]} == {"exited"}
    (commands,) = result["public_report"]["agent_contract"]["checks"]
    assert commands["name"] == "commands" and not commands["passed"]
    assert served.developer.leaderboard("tiny_open")["rows"] == []


@pytest.mark.parametrize("served", ["sqlite", "postgresql"], indirect=True)
def test_killed_evaluator_job_is_released_and_finished_once(served: Served, tmp_path: Path) -> None:
    require_safe_sandbox()
    sub = submit_archive(served, tmp_path, make_package("slow"), "slow")
    proc, work = start_cli_evaluator(served, tmp_path, "victim", "--once")
    try:
        wait_for_episodes(proc, work)
        job, _ = the_job(served, sub["id"])
        assert job["status"] == "evaluating" and job["evaluator"] == "victim"
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    time.sleep(0.5)
    leftovers = [p.name for p in Path("/proc").iterdir() if p.name.isdigit() and _works_in(p, work)]
    assert leftovers == [], "the killed evaluator's worker or agent outlived it"
    assert processes_left(require_safe_sandbox().uid, 5) == [], "the agent outlived the killed evaluator"
    rescuer = evaluator(served, tmp_path, name="rescuer", video=False)
    deadline = time.monotonic() + 20
    status = None
    while status is None:
        assert time.monotonic() < deadline, "the lapsed lease never came back to the queue"
        status = rescuer.take_one()
        time.sleep(0.2)
    assert status == "success"
    job, results = the_job(served, sub["id"])
    assert job["status"] == "success" and job["attempts"] == 2 and job["evaluator"] == "rescuer"
    assert len(results) == 1
    events = [e["kind"] for e in served.admin.get(f"/jobs/{job['id']}")["events"]]
    assert "lease-lapsed" in events


def _works_in(proc_dir: Path, folder: Path) -> bool:
    """Whether a process was started for ``folder`` (the worker names it) or runs in it (an agent)."""
    try:
        cmdline = (proc_dir / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        return str(folder) in cmdline or Path(os.readlink(proc_dir / "cwd")).is_relative_to(folder)
    except OSError:
        return False


def start_cli_evaluator(served: Served, tmp_path: Path, name: str, *args: str) -> tuple[subprocess.Popen, Path]:
    token_file = tmp_path / "ev.token"
    token_file.write_text(served.evaluator_token)
    work = tmp_path / f"work-{name}"
    proc = subprocess.Popen([sys.executable, "-m", "proxybench", "evaluator", "--server", served.url,
                             "--token-file", str(token_file), "--name", name, "--no-video", "--work-dir", str(work),
                             *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    return proc, work


def wait_for_episodes(proc: subprocess.Popen, work: Path) -> None:
    """Until the evaluator's worker is running episodes (after the agent contract's node start and frames)."""
    deadline = time.monotonic() + 90  # a guard against a hang, not a speed limit: the shared 2-core machine is slow
    while not list(work.glob("job-*/runs")):
        assert proc.poll() is None, f"the evaluator ended early:\n{proc.stdout.read() if proc.stdout else ''}"
        assert time.monotonic() < deadline, "the evaluator never started the job"
        time.sleep(0.05)


def test_sigterm_aborts_the_job(served: Served, tmp_path: Path) -> None:
    require_safe_sandbox()
    sub = submit_archive(served, tmp_path, make_package("slow"), "slow-stopped")
    proc, work = start_cli_evaluator(served, tmp_path, "stopped")
    try:
        wait_for_episodes(proc, work)
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, out
    assert "stopped (SIGTERM)" in out
    job, (result,) = the_job(served, sub["id"])
    assert job["status"] == "aborted" and result["status"] == "aborted"
    assert "stopped (SIGTERM) while evaluating" in result["message"]


def test_lost_lease_kills_the_work_and_uploads_nothing(served: Served, tmp_path: Path) -> None:
    require_safe_sandbox()
    sub = submit_archive(served, tmp_path, make_package("slow"), "slow-retired")
    ev = evaluator(served, tmp_path, video=False)
    statuses: list[str | None] = []
    worker = threading.Thread(target=lambda: statuses.append(ev.take_one()))
    worker.start()
    deadline = time.monotonic() + 30
    while the_job(served, sub["id"])[0]["status"] != "evaluating":
        assert time.monotonic() < deadline
        time.sleep(0.05)
    served.developer.post(f"/submissions/{sub['id']}/retire")  # aborts the job: the next heartbeat gets 409
    worker.join(30)
    assert statuses == ["lost"]
    job, results = the_job(served, sub["id"])
    assert job["status"] == "aborted" and results == []


def test_target_job_runs_on_the_reality_model_after_a_compliance_check(served: Served, tmp_path: Path) -> None:
    served.admin.post("/benchmarks", {"yaml": TINY.replace("tiny_eval", "tiny_target"), "features": ["target"],
                                      "hidden_split": False})
    sub = served.developer.submit("pid", "pid-target", benchmark="tiny_target")
    assert evaluator(served, tmp_path, name="sim-only").take_one() is None  # it does not offer 'target'
    ev = evaluator(served, tmp_path, name="lab", features=("sim", "target"), video=False)
    assert ev.take_one() == "success"
    job, (result,) = the_job(served, sub["id"])
    assert job["status"] == "success" and job["evaluator"] == "lab"
    report = result["public_report"]
    assert report["domain_kind"] == "reality-model"
    assert report["compliance"]["ok"] and "not a real robot" in report["compliance"]["target"]
    assert [c["name"] for c in report["compliance"]["checks"]] == ["responds", "camera", "calibration"]


@pytest.mark.parametrize("member", ["../escape.py", "/etc/evil.py"])
def test_server_refuses_path_traversal_archives(served: Served, tmp_path: Path, member: str) -> None:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("proxybench-agent.yaml", "name: evil\nprotocol: aido-z2\ncommand: [python3, agent.py]\n")
        zf.writestr(member, "print('pwned')")
    with pytest.raises(ServerError) as err:
        submit_archive(served, tmp_path, buf.getvalue(), "evil")
    assert err.value.status == 422 and "leaves the package folder" in err.value.message


def test_without_a_safe_sandbox_archives_go_back_to_the_queue(served: Served, tmp_path: Path) -> None:
    sub = submit_archive(served, tmp_path, make_package("ok"), "no-user")
    ev = evaluator(served, tmp_path, name="misconfigured", agent_user="no-such-agent-user", video=False)
    assert ev.take_one() == "host-error"
    job, results = the_job(served, sub["id"])
    events = served.admin.get(f"/jobs/{job['id']}")["events"]
    assert job["status"] == "queued" and results == []
    assert any(e["kind"] == "host-error" and "proxybench sandbox setup" in e["message"] for e in events), events
    assert ev.take_one() is None  # excluded from this job: it waits for an evaluator that can run it


def test_the_developer_flag_runs_the_agent_and_every_report_says_so(served: Served, tmp_path: Path) -> None:
    require_safe_sandbox()  # bubblewrap must work here (as the evaluator's own user)
    sub = submit_archive(served, tmp_path, make_package("ok"), "dev-mode")
    ev = evaluator(served, tmp_path, name="laptop", agent_user="no-such-agent-user", dev_unsafe=True, video=False)
    assert ev.take_one() == "success"
    _, (result,) = the_job(served, sub["id"])
    assert result["message"].startswith("UNSAFE SANDBOX") and "--dev-unsafe-same-user" in result["message"]
    assert result["public_report"]["sandbox"]["safe"] is False
    assert "UNSAFE" in result["public_report"]["sandbox"]["note"]
