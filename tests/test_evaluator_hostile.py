"""Hostile agent packages against a real evaluator: every attack ends ``failed``, nothing leaks, the evaluator
keeps working.

One challenges server (uvicorn in a thread) and one ``proxybench evaluator`` process (as a deployment runs it:
root, agents as the unprivileged agent user) take every case in one session. Each case is a small package
(``tests/hostile_agents/hostile.py CASE``) that attacks at its first command and reports on stderr what it
tried (``ATTEMPTED``), what was stopped (``blocked: ...``) and what got through (``ESCAPED``). Secrets are
planted where a careless operator leaves them: world-readable files, the server's SQLite file, token files,
job files with a hidden test seed, and a listener on 127.0.0.1. After the hostile jobs, a well-behaved agent
must still succeed on the same evaluator.
"""

from __future__ import annotations

import io
import json
import os
import re
import resource
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
import uvicorn

from proxybench.client import ServerClient
from support.sandbox import AGENT_USER_GROUP, processes_left, require_safe_sandbox

pytestmark = AGENT_USER_GROUP  # its agents and evaluators run as the agent user: one test at a time

HOSTILE = Path(__file__).with_name("hostile_agents") / "hostile.py"
TEST_SEED = 738291046
BENCH = """\
name: hostile
description: one short episode; hidden test split with a seed worth stealing
map: small_loop
episodes: {count: 1, seed: 11}
duration: 1.0
physics_rate: 30.0
frame_rate: 5.0
metrics: [survival_time]
scoring:
  - {metric: survival_time_median}
"""
#: case → (a line its stderr must hold: the attack ran and was stopped, the failure reasons it may end with)
CASES: dict[str, tuple[str, tuple[str, ...]]] = {
    "fake_outcome": ("blocked: write {work}/outcome.json", ("exited",)),  # + kill the worker, NUL bytes
    "read_secrets": ("job, token or database files visible: []", ("exited",)),  # + hidden seed, server DB
    "artifacts": ("blocked: write {work}/outcome.json", ("exited",)),
    "network": ("blocked: connect the test's listener, after setns", ("exited",)),  # 127.0.0.1, then setns
    "kill_parent": ("now kill(-1)", ("exited",)),
    "fork_bomb": ("blocked: fork bomb stopped after", ("exited",)),
    "leave_child": ("leaving a daemon behind", ("exited",)),
    "fill_scratch": ("/dev/shm full after", ("exited",)),  # and /scratch, /tmp
    "memory_hog": ("blocked: MemoryError after", ("exited",)),
    "cpu_hog": ("spinning", ("exited", "step-timeout")),
}
#: well-behaved agents: one right after the daemon-leaving case (is the next tenant sabotaged?), one last
GOOD_AFTER = "leave_child"
FORWARD = """\
import sys
import numpy as np
from proxybench.agents.base import Agent
from proxybench.protocol import serve

class Forward(Agent):
    name = "forward"
    def reset(self, seed, episode=None):
        pass
    def act(self, obs):
        return np.array([0.3, 0.3])

sys.exit(serve(Forward()))
"""


class Listener(threading.Thread):
    """A TCP listener on 127.0.0.1 that records every connection (an agent must never reach it)."""

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.sock = socket.create_server(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.connections: list[bytes] = []
        self.start()

    def run(self) -> None:
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            with conn:
                conn.settimeout(1)
                try:
                    self.connections.append(conn.recv(200))
                except OSError:
                    self.connections.append(b"")


@dataclass
class Session:
    """What the hostile session left behind, for the per-case assertions."""

    jobs: dict[str, dict] = field(default_factory=dict)
    results: dict[str, dict] = field(default_factory=dict)
    artifact_bytes: dict[str, list[tuple[str, bytes]]] = field(default_factory=dict)
    secrets: dict[str, str] = field(default_factory=dict)
    paths: dict[str, str] = field(default_factory=dict)
    listener: Listener | None = None
    evaluator_alive: bool = False
    evaluator_output: str = ""
    leftovers: list[str] = field(default_factory=list)
    host_files: list[str] = field(default_factory=list)
    job_seconds: dict[str, float] = field(default_factory=dict)  # leased → result stored
    wall_s: float = 0.0
    cpu_s: dict[str, float] = field(default_factory=dict)  # the evaluator's process tree; this test process


def _package(label: str, files: dict[str, bytes], command: list[str]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("proxybench-agent.yaml", f"name: {label}\nprotocol: aido-z2\ncommand: {json.dumps(command)}\n")
        for name, data in files.items():
            zf.writestr(name, data)
    return buf.getvalue()


def _start_server(data_dir: Path):
    from proxybench.server.app import create_app
    from proxybench.server.config import Settings

    app = create_app(Settings(data_dir=data_dir, lease_seconds=10.0, daily_submission_limit=0))
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 20
    while not server.started:
        assert time.monotonic() < deadline, "server did not start"
        time.sleep(0.02)
    return app, server, thread, server.servers[0].sockets[0].getsockname()[1]


def _wait_final(admin: ServerClient, subs: dict[str, int], proc: subprocess.Popen, timeout: float) -> dict[str, dict]:
    """Every submission's job once none is queued or evaluating (or the evaluator died, or time ran out)."""
    deadline = time.monotonic() + timeout
    label_of = {sid: label for label, sid in subs.items()}
    while True:
        jobs = {label_of[j["submission_id"]]: j for j in admin.get("/jobs") if j["submission_id"] in label_of}
        done = all(j["status"] not in ("queued", "evaluating") for j in jobs.values()) and len(jobs) == len(subs)
        if done or proc.poll() is not None or time.monotonic() > deadline:
            return jobs
        time.sleep(1.0)


@pytest.fixture(scope="module")
def session() -> Session:
    return run_session(list(CASES))


def run_session(cases: list[str], keep_work: Path | None = None) -> Session:
    """Submit the ``cases`` (and the well-behaved agents) and let one evaluator process take them all."""
    isolation = require_safe_sandbox()
    t0 = time.monotonic()
    before = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    out = Session()
    base = Path(tempfile.mkdtemp(prefix="proxybench-hostile-"))
    base.chmod(0o755)  # a careless operator: everything here is world-readable, only the sandbox protects it
    work, data = base / "work", base / "server"
    app, server, thread, port = _start_server(data)
    listener = out.listener = Listener()
    admin = ServerClient(f"http://127.0.0.1:{port}", app.state.admin_token, retry_for=5)
    proc = None
    try:
        ev = admin.post("/users", {"name": "ev", "role": "evaluator"})
        dev = admin.post("/users", {"name": "dev", "role": "developer"})
        admin.post("/benchmarks", {"yaml": BENCH, "features": ["sim"], "test_seed": TEST_SEED})
        admin.post("/benchmarks", {"yaml": BENCH.replace("name: hostile", "name: hostile_open"), "features": ["sim"],
                                   "hidden_split": False})  # the well-behaved agents: one episode only
        token_file = base / "evaluator.token"
        token_file.write_text(ev["token"])
        token_file.chmod(0o644)
        planted = base / "operator-notes.txt"
        out.secrets = {"admin token": app.state.admin_token, "evaluator token": ev["token"],
                       "developer token": dev["token"], "planted": "PLANTED-" + secrets.token_hex(8),
                       "hidden seed": str(TEST_SEED)}
        planted.write_text(out.secrets["planted"])
        planted.chmod(0o644)
        shadow = Path("/etc/shadow").read_text().splitlines()
        out.secrets["/etc/shadow"] = next(line for line in shadow if line.startswith("root:"))
        db = data / "server.sqlite3"
        out.paths = {"work": str(work), "db": str(db)}
        proc = subprocess.Popen(
            [sys.executable, "-m", "proxybench", "evaluator", "--server", f"http://127.0.0.1:{port}", "--token-file",
             str(token_file), "--name", "hostile", "--work-dir", str(work), "--no-video", "--poll", "0.2",
             "--cpu-seconds", "3", "--memory-mb", "640", "--file-mb", "64", "--scratch-mb", "32",
             *(["--keep-work"] if keep_work else [])],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
        targets = json.dumps({
            "secrets": [str(data / "admin.token"), str(token_file), str(planted), "/etc/shadow"],
            "work_dir": str(work), "data_dir": str(data), "db": str(db), "evaluator_pid": proc.pid,
            "listener_port": listener.port, "server_port": port}).encode()
        developer = ServerClient(f"http://127.0.0.1:{port}", dev["token"], retry_for=5)
        subs: dict[str, int] = {}
        order = [*cases, "good-last"]
        if GOOD_AFTER in order:
            order.insert(order.index(GOOD_AFTER) + 1, "good-after-daemon")
        for label in order:
            if label.startswith("good"):
                data_zip = _package(label, {"agent.py": FORWARD.encode()}, ["python3", "agent.py"])
            else:
                data_zip = _package(label, {"hostile.py": HOSTILE.read_bytes(), "targets.json": targets},
                                    ["python3", "hostile.py", label])
            path = base / f"{label}.zip"
            path.write_bytes(data_zip)
            bench = "hostile_open" if label.startswith("good") else "hostile"
            subs[label] = developer.submit_archive(path, label, benchmark=bench)["id"]
            path.unlink()
        developer.close()
        out.jobs = _wait_final(admin, subs, proc, timeout=400)
        out.evaluator_alive = proc.poll() is None
        for label, sid in subs.items():
            events = admin.get(f"/jobs/{out.jobs[label]['id']}")["events"]
            times = [e["at"] for e in events if e["kind"] not in ("created", "queued")]
            out.job_seconds[label] = max(times) - min(times) if times else float("nan")
            results = admin.get(f"/submissions/{sid}")["results"]
            out.results[label] = results[-1] if results else {}
            out.artifact_bytes[label] = [(a["name"], admin.get_artifact(a["sha256"]))
                                         for a in out.results[label].get("artifacts", [])]
        uid = isolation.uid
        assert uid is not None
        out.leftovers = processes_left(uid)  # the last job's sandbox may still be exiting as its result is stored
        out.host_files = [p for p in ("/tmp/hostile-daemon", "/tmp/hostile-fill", "/dev/shm/hostile-fill",
                                      "/tmp/outcome.json") if os.path.lexists(p)]
        out.host_files += [str(p) for p in work.rglob("*") if p.name in ("outcome.json", "hostile-fill")]
    finally:
        if proc is not None:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            try:
                out.evaluator_output = proc.communicate(timeout=30)[0]
            except subprocess.TimeoutExpired:
                os.killpg(proc.pid, signal.SIGKILL)
                out.evaluator_output = proc.communicate()[0]
        admin.close()
        listener.sock.close()
        server.should_exit = True
        thread.join(timeout=10)
        if keep_work:
            shutil.copytree(work, keep_work, dirs_exist_ok=True)
        shutil.rmtree(base, ignore_errors=True)
    out.wall_s = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    out.cpu_s = {who: (b.ru_utime + b.ru_stime) - (a.ru_utime + a.ru_stime)
                 for who, a, b in (("test process and server", before[0], after[0]),
                                   ("evaluator, workers, agents", before[1], after[1]))}
    print(f"\nhostile session: {len(subs)} jobs in {out.wall_s:.1f} s; CPU s: "
          + ", ".join(f"{who} {s:.1f}" for who, s in out.cpu_s.items()) + "; per job (lease → result), s:")
    for label, seconds in out.job_seconds.items():
        print(f"  {label:18s} {out.jobs[label]['status']:8s} {seconds:5.1f}")
    return out


def _texts(sess: Session, label: str) -> list[tuple[str, bytes]]:
    """Everything stored for a job: the result (all reports, message), each artifact and each zip member."""
    result = sess.results[label]
    parts = [("result", json.dumps(result).encode()), ("job", json.dumps(sess.jobs[label]).encode())]
    for name, data in sess.artifact_bytes[label]:
        parts.append((name, data))
        if data[:2] == b"PK":
            with zipfile.ZipFile(io.BytesIO(data)) as zf:
                parts += [(f"{name}/{m}", zf.read(m)) for m in zf.namelist()]
    return parts


def _stderr(result: dict) -> str:
    return "\n".join(line for f in result.get("public_report", {}).get("agent_failures", [])
                     for line in f.get("stderr_tail", []))


@pytest.mark.parametrize("case", list(CASES))
def test_hostile_agent_fails_and_leaks_nothing(session: Session, case: str) -> None:
    job, result = session.jobs[case], session.results[case]
    assert job["status"] == "failed", f"{case}: {job['status']}: {job.get('message')}\n{session.evaluator_output}"
    assert result["status"] == "failed" and result["public_scores"] == {}
    failures = result["public_report"]["agent_failures"]
    evidence, reasons = CASES[case]
    assert failures and all(f["reason"] in reasons for f in failures), failures
    stderr = _stderr(result)
    assert f"ATTEMPTED {case}" in stderr, stderr  # the attack did run, in the sandbox
    assert evidence.format(**session.paths) in stderr, stderr  # ... and was stopped
    for where, data in _texts(session, case):
        assert b"ESCAPED" not in data, f"{case}: an attack got through ({where})"
        for name, secret in session.secrets.items():
            assert secret.encode() not in data, f"{case}: the {name} is in {where}"
    sandbox = result["public_report"]["sandbox"]
    assert sandbox["safe"] and sandbox["user"] == "proxybench-agent" and "UNSAFE" not in result["message"]


def test_no_attack_reached_the_host(session: Session) -> None:
    assert session.listener is not None and session.listener.connections == []
    assert session.host_files == [], "agents wrote outside their sandbox"
    assert session.leftovers == [], "processes of the agent user outlived their jobs"


def test_the_evaluator_survived_and_took_the_next_jobs(session: Session) -> None:
    assert session.evaluator_alive, session.evaluator_output
    for label in ("good-after-daemon", "good-last"):
        job = session.jobs[label]
        assert job["status"] == "success", f"{label}: {job.get('message')}"
        assert job["attempts"] == 1 and session.results[label]["public_scores"]["survival_time_median"] > 0.5
    statuses = [j["status"] for j in session.jobs.values()]
    assert statuses.count("failed") == len(CASES) and "error" not in statuses
    assert re.search(r"host-error|aborted", session.evaluator_output) is None, session.evaluator_output
