"""Demo content for the web console's screenshots and browser tests, entered through the JSON API.

:func:`seed_demo` plays operator, developers and one evaluator against a fresh server: it creates users
and a benchmark path, submits built-in agents, and then leases the jobs and uploads results for them as
an evaluator would. The results are **invented** (drawn from a seeded generator per submission, no
simulation runs), which is all a page needs; every row is stored by the server's own code paths.
"""

from __future__ import annotations

import hashlib
import math
import threading
import time
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import httpx
import numpy as np

from proxybench.domain.events import Termination
from proxybench.server.benchmarks import parse_benchmark
from proxybench.tasks.aggregate import aggregate, scores_by_agent
from proxybench.tasks.benchmark import derive_seed

__all__ = ["DemoData", "demo_scores", "seed_demo", "serve_in_thread"]

API = "/api/v1"
PATH_NAME = "sim-then-target"
#: (user, label, agent, benchmark or None for the path, what the evaluator does, skill in [0, 1])
PLAN = (
    ("alice", "vision baseline", "vision", "aido_lf", "success", 0.80),
    ("alice", "vision pitch 15", "vision-pitch15", "aido_lf", "success", 0.92),
    ("bob", "vision v2", "vision-slow", "aido_lf", "success", 0.62),
    ("bob", "random walk", "random", "aido_lf", "failed", 0.0),
    ("bob", "vision fast", "vision-fast", "aido_lf", "error", 0.5),
    ("alice", "pid loop", "pid", "thesis_loop", "success", 0.85),
    ("bob", "pursuit loop", "pure-pursuit", "thesis_loop", "success", 0.9),
    ("bob", "vision loop", "vision", "thesis_loop", "success", 0.55),
    ("alice", "vision to target", "vision-pitch25", None, "success", 0.82),
    ("bob", "vision wide", "vision-wide", "aido_lf", "evaluating", 0.6),
)
MESSAGES = {
    "failed": "agent process exited with code 1 after 3.2 s: ValueError: observation has no 'camera'",
    "error": "evaluator error: CUDA out of memory while rendering episode 2 (tried to allocate 1.2 GiB)",
}


@dataclass
class DemoData:
    """What :func:`seed_demo` made: tokens by user name, submission ids by label, job ids by outcome."""

    tokens: dict[str, str] = field(default_factory=dict)
    submissions: dict[str, int] = field(default_factory=dict)
    jobs: dict[str, list[int]] = field(default_factory=dict)


def _call(client: httpx.Client, method: str, url: str, token: str, **kw: Any) -> httpx.Response:
    r = client.request(method, API + url, headers={"Authorization": f"Bearer {token}", **kw.pop("headers", {})},
                       **kw)
    if r.status_code >= 400:
        raise RuntimeError(f"{method} {url}: {r.status_code} {r.text[:300]}")
    return r


def _episode(rng: np.random.Generator, skill: float, duration: float) -> dict[str, float]:
    """Plausible lane-following metrics of one episode for an agent of this skill."""
    survived = duration if rng.random() < 0.25 + 0.75 * skill else float(rng.uniform(0.1, 0.9) * duration)
    speed = 0.05 + 0.25 * skill * float(rng.uniform(0.85, 1.05))  # m/s along the lane
    dist = survived * speed
    return {"survival_time": survived, "driven_lanedir_consec": dist * float(rng.uniform(0.8, 1.0)), "distance": dist,
            "deviation_center_line": survived * (0.002 + 0.02 * (1 - skill)) * float(rng.uniform(0.7, 1.3)),
            "in_drivable_lane": survived * (1 - skill) * float(rng.uniform(0.0, 0.1)),
            "deviation_heading": survived * (0.05 + 0.3 * (1 - skill)) * float(rng.uniform(0.7, 1.3))}


def demo_scores(spec_yaml: str, label: str, skill: float, seeds: list[int]) -> tuple[dict, dict]:
    """(scores, report) for one split, shaped as ``proxybench.evaluator.report.summarize`` makes them: every
    aggregated column (``<metric>_<stat>``, its bootstrap interval, ``<metric>_n``, ``episodes``)."""
    bench = parse_benchmark(spec_yaml)
    episodes = []
    for i, seed in enumerate(seeds):
        rng = np.random.default_rng([zlib.crc32(label.encode()), seed])
        values = _episode(rng, skill, bench.duration)
        ended = Termination.TIMEOUT if values["survival_time"] >= bench.duration else Termination.OFF_ROAD
        episodes.append({"episode": i, "seed": seed, "termination": ended, "duration": values["survival_time"],
                         "scores": {m: round(values[m], 4) for m in bench.metrics}, "events": [], "message": ""})
    table = [{"agent": label, "domain": "demo", "episode": e["episode"], "metric": m, "value": v}
             for e in episodes for m, v in e["scores"].items()]
    raw = next(iter(scores_by_agent(aggregate(table, n_resamples=1000)).values()))
    scores = {k: round(v, 4) if math.isfinite(v) else None for k, v in raw.items()}  # as the evaluator's clean()
    for c in bench.criteria():
        scores.setdefault(c.metric, None)
    terminations: dict[str, int] = {}
    for e in episodes:
        terminations[e["termination"]] = terminations.get(e["termination"], 0) + 1
    return scores, {"benchmark": bench.name, "episodes": episodes, "terminations": terminations,
                    "criteria": [c.metric for c in bench.criteria()]}


def _upload(client: httpx.Client, token: str, data: bytes, media: str, job: dict[str, Any]) -> str:
    """Upload under the job's lease (a result names only artifacts its lease uploaded)."""
    sha = hashlib.sha256(data).hexdigest()
    _call(client, "PUT", f"/artifacts/{sha}", token, content=data, headers={"content-type": media},
          params={"job_id": job["job_id"], "lease_id": job["lease_id"]})
    return sha


def seed_demo(client: httpx.Client, admin_token: str, *, video: bytes | None = None) -> DemoData:
    """Fill an empty server with users, a path, submissions, results and a job in each state.

    ``client`` reaches the server (``fastapi.testclient.TestClient(app)`` or ``httpx.Client(base_url=…)``);
    ``video`` (MP4 bytes), when given, is attached to one result.
    """
    out = DemoData(tokens={"admin": admin_token})
    for name, role in (("alice", "developer"), ("bob", "developer"), ("lab-1", "evaluator")):
        made = _call(client, "POST", "/users", admin_token, json={"name": name, "role": role})
        out.tokens[name] = made.json()["token"]
    path = {"steps": [{"id": "sim", "benchmark": "aido_lf"},
                      {"id": "target", "benchmark": "aido_lf", "features": ["target"]}],
            "edges": [{"source": "sim", "target": "target",
                       "condition": {"metric": "survival_time_median", "min": 30}}]}
    _call(client, "POST", "/paths", admin_token, json={"name": PATH_NAME, "spec": path, "description":
          "Lane following in simulation first; agents that survive 30 s (median) go on to the target robots."})
    plan = {}
    for user, label, agent, bench, outcome, skill in PLAN:
        body = {"label": label, "agent": agent, **({"benchmark": bench} if bench else {"path": PATH_NAME})}
        sub = _call(client, "POST", "/submissions", out.tokens[user], json=body).json()
        out.submissions[label] = sub["id"]
        plan[sub["id"]] = (outcome, skill)
    evaluator = out.tokens["lab-1"]
    while True:
        r = _call(client, "POST", "/jobs/lease", evaluator,
                  json={"evaluator": "lab-1", "features": ["sim"], "version": "0.1.0"})
        if r.status_code == 204:
            break
        job = r.json()
        outcome, skill = plan[job["submission"]["id"]]
        out.jobs.setdefault(outcome, []).append(job["job_id"])
        if outcome == "evaluating":
            _call(client, "POST", f"/jobs/{job['job_id']}/heartbeat", evaluator,
                  json={"lease_id": job["lease_id"], "evaluator": "lab-1", "progress": {"done": 2, "total": 5}})
            continue
        _finish(client, evaluator, job, outcome, skill, video)
    return out


def _finish(client: httpx.Client, token: str, job: dict[str, Any], outcome: str, skill: float,
            video: bytes | None) -> None:
    bench, label = job["benchmark"], job["submission"]["label"]
    body: dict[str, Any] = {"lease_id": job["lease_id"], "evaluator": "lab-1", "status": outcome,
                            "message": MESSAGES.get(outcome, "")}
    if outcome == "failed":  # the agent crashed in its first episode: the evaluator reports what it saw
        first = parse_benchmark(bench["spec_yaml"]).episode_specs()[0]
        _, report = demo_scores(bench["spec_yaml"], label, 0.0, [first.seed])
        report["episodes"][0].update(termination=Termination.AGENT_FAILURE, message=MESSAGES["failed"])
        report["agent_failures"] = [{"episode": 0, "reason": "exited", "message": MESSAGES["failed"], "stderr_tail": [
            "Traceback (most recent call last):", '  File "agent.py", line 12, in on_observation',
            "    image = obs['camera']", "ValueError: observation has no 'camera'"]}]
        body["public_report"] = report
    if outcome == "success":
        spec = parse_benchmark(bench["spec_yaml"])
        seeds = [e.seed for e in spec.episode_specs()]
        body["public_scores"], body["public_report"] = demo_scores(bench["spec_yaml"], label, skill, seeds)
        if bench.get("test_seed") is not None:
            hidden = [derive_seed(bench["test_seed"], i) for i in range(len(seeds))]
            body["hidden_scores"], body["hidden_report"] = demo_scores(bench["spec_yaml"], label + "/test", skill,
                                                                       hidden)
    log = (f"evaluator lab-1 (proxybench 0.1.0), job {job['job_id']} attempt {job['attempt']}\n"
           f"benchmark {bench['name']} v{bench['version']}, submission {label!r}\n"
           f"outcome: {outcome}\n{body['message']}\n").encode()
    arts = [{"name": "evaluator.log", "sha256": _upload(client, token, log, "text/plain", job)}]
    if outcome == "success":
        hidden_log = b"hidden test episodes: per-episode details for operators only\n"
        arts.append({"name": "test/episodes.log", "sha256": _upload(client, token, hidden_log, "text/plain", job),
                     "hidden": True})
        if video is not None and label == "vision v2":
            arts.append({"name": "episode-0.mp4", "sha256": _upload(client, token, video, "video/mp4", job)})
    body["artifacts"] = arts
    _call(client, "POST", f"/jobs/{job['job_id']}/result", token, json=body)


@contextmanager
def serve_in_thread(app: Any, host: str = "127.0.0.1", port: int = 0) -> Iterator[str]:
    """Run ``app`` under uvicorn in a daemon thread (``port=0``: a free one); yields the base URL."""
    import uvicorn

    server = uvicorn.Server(uvicorn.Config(app, host=host, port=port, log_level="warning", lifespan="off"))
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise RuntimeError("the web server did not start")
        time.sleep(0.02)
    bound = server.servers[0].sockets[0].getsockname()[1]
    try:
        yield f"http://{host}:{bound}"
    finally:
        server.should_exit = True
        thread.join(timeout=10)
