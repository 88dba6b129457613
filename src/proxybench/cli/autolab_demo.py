"""`proxybench autolab demo`: a whole simulated Autolab on this machine, started by one command (issue 36 item 5).

It stands up, on loopback only, what the seed's benchmarking network is: the challenges server (in this process,
SQLite in ``OUT/server``), a lab (``OUT/lab.yaml``: virtual DB21Js and simulated watchtowers), an Autolab
evaluator (``proxybench evaluator --autolab``, a process of its own in its own session), and a developer who
submits the built-in lane-following duckietown-sdk agent package. It follows the job, prints the result and the
leaderboard's URL, and (without ``--once``) keeps the lab serving until Ctrl-C, which stops the evaluator (its
job aborted, its agent and robot gone) and then the server. ``--once`` runs the one submission end to end and
writes ``OUT/job.json``.

This lives in ``cli/`` because it is the one place that holds the server, the evaluator and the client together
(they are siblings in docs/DESIGN.md's layers, none may import another).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
import time
import zipfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field

__all__ = ["BENCHMARK", "LANE_AGENT", "DemoError", "DemoOptions", "JobSummary", "run_demo"]

#: the demo benchmark's name on its server
BENCHMARK = "autolab_demo"
#: the built-in agent: lane following written against duckietown-sdk's public API only (as its README shows it);
#: the same program runs on the Duckiematrix or a real DB21J. The tests' SDK lane follower is this one
#: (tests/test_dtps.py, test_autolab_evaluator.py, ...)
LANE_AGENT = '''\
"""Lane following with duckietown-sdk: steer between the yellow centre line and the white edge."""
import numpy as np
from duckietown.sdk.robots.duckiebot import DB21J

robot = DB21J("map_0/vehicle_0", simulated=True)
robot.camera.start()
robot.motors.start()
while True:
    bgr = robot.camera.capture(block=True)
    if bgr is None:
        continue
    h, w = bgr.shape[:2]
    low = bgr[h // 2:].astype(np.int16)
    yellow = (low[..., 2] > 150) & (low[..., 1] > 120) & (low[..., 0] < 100)
    white = low.min(axis=2) > 170
    xs_y, xs_w = np.nonzero(yellow)[1], np.nonzero(white)[1]
    centre = w / 2
    if xs_y.size and xs_w.size:
        centre = (xs_y.mean() + xs_w.mean()) / 2
    elif xs_y.size:
        centre = xs_y.mean() + 0.3 * w
    elif xs_w.size:
        centre = xs_w.mean() - 0.3 * w
    err = (centre - w / 2) / (w / 2)
    robot.motors.set_pwm(0.25 + 0.15 * err, 0.25 - 0.15 * err)
'''
_MANIFEST = ("name: sdk-lane\nprotocol: duckietown-sdk\ncommand: python3 lane.py\ntiming: lockstep\n"
             "start_timeout: 120\n")
_OPEN = ("queued", "evaluating")


class DemoError(RuntimeError):
    """The demo cannot start or its lab stopped; the message says what to do."""


class DemoOptions(BaseModel):
    """What the demo lab looks like and how long it runs (the command's options)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    out: Path | None = None
    once: bool = False
    port: int = Field(0, ge=0, le=65535)
    map: str = "loop_3x3"
    seconds: float = Field(10.0, gt=0.0, le=120.0)
    frame_rate: float = Field(10.0, gt=0.0, le=30.0)
    watchtower_rate: float = Field(5.0, gt=0.0, le=30.0)
    dev_unsafe: bool = False
    video: bool = True


class JobSummary(BaseModel):
    """``OUT/job.json``: how the demo's submission ended, as the server stores it."""

    model_config = ConfigDict(extra="forbid")

    submission: int
    job: int
    status: str
    message: str
    scores: dict[str, float | None]
    localization_median_error_m: float | None
    robot_reported_scores: dict[str, float | None] = Field(default_factory=dict)
    measured_by: str | None = None
    leaderboard: str


def preflight(options: DemoOptions) -> None:
    """What a lab needs on this machine, checked before anything starts: :class:`DemoError` saying what is missing."""
    from proxybench.dtps.env import DtpsEnvError, sdk_python
    from proxybench.evaluator.sandbox import detect_isolation

    try:
        sdk_python()
    except DtpsEnvError as exc:
        raise DemoError(f"the SDK agent needs duckietown-sdk's environment: {exc}") from None
    isolation = detect_isolation(dev_unsafe=options.dev_unsafe)
    if not isolation.safe and not options.dev_unsafe:
        raise DemoError(f"no agent sandbox here ({isolation.problem or isolation.note}); run `proxybench sandbox "
                        "setup` as root, or pass --dev-unsafe-same-user on a development machine")


def demo_folder(out: Path | None) -> Path:
    """``out`` (new or empty: the demo never writes over what is there) or a fresh temporary folder."""
    if out is None:
        return Path(tempfile.mkdtemp(prefix="proxybench-autolab-"))
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise DemoError(f"--out {out}: not an empty folder; give a new one (the demo writes over nothing)")
    out.mkdir(parents=True, exist_ok=True)
    os.chmod(out, 0o700)  # tokens and the evaluator's work live here
    return out


def write_lab(folder: Path, options: DemoOptions) -> Path:
    """``lab.yaml`` (two virtual DB21Js: two jobs at once, each robot in a world of its own) with its simulated
    watchtowers' layout (``watchtowers.yaml``, at the demo's frame rate), checked as ``autolab check`` would."""
    import yaml

    from proxybench.autolab.lab import check_lab, load_lab
    from proxybench.autolab.watchtowers import auto_layout, write_layout
    from proxybench.domain.maps import load_map

    write_layout(folder / "watchtowers.yaml", auto_layout(load_map(options.map), frame_rate=options.watchtower_rate))
    lab = {"format": "proxybench-lab/1", "name": "demo-lab", "map": options.map,
           "robots": [{"name": "db1", "virtual": True}, {"name": "db2", "virtual": True}],
           "watchtowers": {"layout": "watchtowers.yaml"},
           "reset": {"mode": "teleport"}, "limits": {"max_episode_s": max(120.0, options.seconds)}}
    path = folder / "lab.yaml"
    path.write_text(yaml.safe_dump(lab, sort_keys=False))
    check_lab(load_lab(path), str(path))
    return path


def benchmark_yaml(options: DemoOptions) -> str:
    """The demo's benchmark: one episode of lane following on the lab's map, the camera at ``frame_rate``."""
    import yaml

    return yaml.safe_dump({
        "name": BENCHMARK, "description": "lane following in the demo Autolab, measured by its watchtowers",
        "map": options.map, "episodes": {"count": 1, "seed": 3}, "duration": options.seconds,
        "physics_rate": 30.0, "frame_rate": options.frame_rate, "camera_only": True,
        "metrics": ["survival_time", "driven_lanedir_consec", "deviation_center_line"],
        "scoring": [{"metric": "driven_lanedir_consec_median", "higher_is_better": True},
                    {"metric": "survival_time_median"}]}, sort_keys=False)


def agent_package(folder: Path) -> Path:
    """The built-in SDK agent (:data:`LANE_AGENT`) as an agent package."""
    path = folder / "sdk-lane.zip"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("proxybench-agent.yaml", _MANIFEST)
        zf.writestr("lane.py", LANE_AGENT)
    return path


def _secret(path: Path, token: str) -> Path:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(token + "\n")
    return path


@contextmanager
def served(folder: Path, port: int) -> Iterator[tuple[str, str]]:
    """The challenges server in a thread of this process on 127.0.0.1 (SQLite in ``folder/server``); yields its
    URL and admin token and stops it on the way out."""
    import uvicorn

    from proxybench.server.app import create_app
    from proxybench.server.config import Settings
    from proxybench.server.connections import PROTOCOL

    settings = Settings(data_dir=folder / "server")
    app = create_app(settings)
    server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", http=PROTOCOL,
                                           timeout_keep_alive=settings.idle_timeout))
    thread = threading.Thread(target=server.run, name="autolab-demo-server", daemon=True)
    thread.start()
    while not server.started:
        if not thread.is_alive():
            raise DemoError(f"the server did not start on 127.0.0.1:{port} (is the port taken?)")
        time.sleep(0.05)
    bound = server.servers[0].sockets[0].getsockname()[1]
    try:
        yield f"http://127.0.0.1:{bound}", app.state.admin_token
    finally:
        server.should_exit = True
        thread.join(timeout=30)


def evaluator_command(url: str, token_file: Path, lab: Path, work: Path, options: DemoOptions) -> list[str]:
    """The lab's Autolab evaluator: ``proxybench evaluator --autolab`` against the demo's server."""
    cmd = [sys.executable, "-m", "proxybench", "evaluator", "--server", url, "--token-file", str(token_file),
           "--name", "demo-lab", "--features", "sim", "--autolab", str(lab), "--work-dir", str(work), "--poll", "0.5"]
    if options.once:
        cmd.append("--once")
    if not options.video:
        cmd.append("--no-video")
    if options.dev_unsafe:
        cmd.append("--dev-unsafe-same-user")
    return cmd


@contextmanager
def evaluator_process(cmd: list[str], log_path: Path) -> Iterator[subprocess.Popen]:
    """The evaluator in a session of its own (a terminal's Ctrl-C reaches the demo only); on the way out it is
    asked to stop (SIGTERM: it aborts its job and ends its worker and agent), killed if it does not."""
    env = {k: v for k, v in os.environ.items() if k not in ("PROXYBENCH_TOKEN", "PROXYBENCH_TOKEN_FILE")}
    with open(log_path, "ab") as log:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT, env=env,
                                start_new_session=True)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def summarize(client, sub_id: int, board_url: str) -> JobSummary:
    """The submission's job as the server has it: status, message (the result's, else the job's last event), the
    localised scores and the localisation's error against the virtual robot's truth."""
    sub = client.get(f"/submissions/{sub_id}")
    (job,) = sub["jobs"]
    result = next((r for r in sub["results"] if r.get("job_id", job["id"]) == job["id"]), None)
    report = (result or {}).get("public_report") or {}
    message = (result or {}).get("message") or ""
    if not message:
        events = client.get(f"/jobs/{job['id']}").get("events") or []
        message = events[-1]["message"] if events else ""
    status = job["status"]
    if status in _OPEN and result is None:  # back in the queue after the lab's fault: say which
        events = client.get(f"/jobs/{job['id']}").get("events") or []
        faults = [e for e in events if e["kind"] == "host-error"]
        status, message = ("host-error", faults[-1]["message"]) if faults else (status, message)
    return JobSummary(submission=sub_id, job=job["id"], status=status, message=message,
                      scores=(result or {}).get("public_scores") or {},
                      localization_median_error_m=report.get("localization_median_error_m"),
                      robot_reported_scores=report.get("robot_reported_scores") or {},
                      measured_by=report.get("measured_by"), leaderboard=board_url)


def wait_for_job(admin, sub_id: int, evaluator: subprocess.Popen, say: Callable[[str], None]) -> None:
    """Until the submission's job is final, or the lab gave it back (a host-error: this lab is excluded from it
    now), or the evaluator has ended (``--once``), saying each change."""
    seen = None
    while True:
        (job,) = admin.get(f"/submissions/{sub_id}")["jobs"]
        if job["status"] != seen:
            seen = job["status"]
            say(f"job {job['id']}: {seen}")
        if seen not in _OPEN or evaluator.poll() is not None:
            return
        if seen == "queued" and any(e["kind"] == "host-error" for e in admin.get(f"/jobs/{job['id']}")["events"]):
            return
        time.sleep(0.5)


def run_demo(options: DemoOptions, say: Callable[[str], None]) -> JobSummary:
    """Stand up the lab, submit the built-in agent, follow its job (see the module); with ``--once`` return its
    summary (also in ``OUT/job.json``), else serve until Ctrl-C (KeyboardInterrupt, raised through)."""
    from proxybench.client import ServerClient

    folder = demo_folder(options.out)
    preflight(options)
    say(f"demo folder {folder}")
    lab = write_lab(folder, options)
    with served(folder, options.port) as (url, admin_token), ServerClient(url, admin_token, retry_for=10) as admin:
        ev_user = admin.post("/users", {"name": "demo-lab", "role": "evaluator"})
        ev_token = _secret(folder / "evaluator.token", ev_user["token"])
        dev_token = admin.post("/users", {"name": "demo", "role": "developer"})["token"]
        _secret(folder / "developer.token", dev_token)
        admin.post("/benchmarks", {"yaml": benchmark_yaml(options), "features": ["autolab"], "hidden_split": False})
        board = f"{url}/leaderboards/{BENCHMARK}"
        say(f"server {url} (admin token {folder / 'server' / 'admin.token'}, developer token "
            f"{folder / 'developer.token'})")
        say(f"lab {lab}: virtual robots db1 and db2 (one job each at once), simulated watchtowers at "
            f"{options.watchtower_rate:g} Hz")
        cmd = evaluator_command(url, ev_token, lab, folder / "evaluator", options)
        with evaluator_process(cmd, folder / "evaluator.log") as ev, ServerClient(url, dev_token) as dev:
            say(f"Autolab evaluator started (pid {ev.pid}, log {folder / 'evaluator.log'})")
            sub = dev.submit_archive(agent_package(folder), "sdk-lane", benchmark=BENCHMARK)
            say(f"submitted the built-in SDK agent sdk-lane (submission {sub['id']}); leaderboard: {board}")
            wait_for_job(admin, sub["id"], ev, say)
            summary = summarize(admin, sub["id"], board)
            (folder / "job.json").write_text(summary.model_dump_json(indent=2) + "\n")
            say(f"wrote {folder / 'job.json'}")
            if options.once:
                return summary
            say(f"{summary.status}: {summary.message}")
            say(f"leaderboard: {board}  (Ctrl-C stops the lab)")
            while ev.poll() is None:
                time.sleep(0.5)
            raise DemoError(f"the evaluator stopped (exit {ev.returncode}); see {folder / 'evaluator.log'}")
