"""The queue under races (issue 23 §3): results posted across their lease's expiry, evaluators and the server
killed -9 during load. Used by tests/test_queue_races.py (short) and benchmarks/bench_queue_races.py.

A real ``proxybench serve`` (two worker processes) with short leases; submitters in this process; evaluator
processes (``race_evaluator.py``) that post each result after a random time around the lease's length and
log every acknowledged one; every ``kill_every`` seconds one evaluator is killed -9 and started again, and
the server is killed -9 once and restarted. Then the queue is drained and the database is read:

- **lost**: an acknowledged result that is not stored under its lease;
- **duplicated**: a job with two results, or two leases of one job both acknowledged;
- **disagreements**: a job whose status is not its result's (success ⇔ a success result), a job leased
  again after its result was stored, a leaderboard whose rows are not the successful jobs.
"""

from __future__ import annotations

import contextlib
import os
import random
import signal
import subprocess
import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from sqlalchemy import create_engine, text

from proxybench.client import ServerClient, ServerError
from support.live_server import LiveServer

__all__ = ["RaceFigures", "race"]

_EVALUATOR = Path(__file__).with_name("race_evaluator.py")


@dataclass
class RaceFigures:
    """What one race run did and found."""

    seconds: float = 0.0
    submissions: int = 0
    acknowledged: int = 0
    late: int = 0  # acknowledged results posted after their lease had lapsed
    posted_late: int = 0  # results posted after their lease had lapsed: acknowledged, or refused (409)
    evaluator_kills: int = 0
    server_kills: int = 0
    lost: list[str] = field(default_factory=list)
    duplicated: list[str] = field(default_factory=list)
    disagreements: list[str] = field(default_factory=list)
    open_jobs: int = 0  # still queued or evaluating after the drain
    jobs: Counter = field(default_factory=Counter)

    def line(self) -> str:
        return (f"{self.seconds:.0f} s: {self.submissions} submissions, {self.acknowledged} results acknowledged; "
                f"{self.posted_late} posted after their lease lapsed ({self.late} acknowledged, the rest refused), "
                f"{self.evaluator_kills} evaluator kills, "
                f"{self.server_kills} server kills; lost {len(self.lost)}, duplicated {len(self.duplicated)}, "
                f"status/leaderboard disagreements {len(self.disagreements)}; jobs {dict(self.jobs)}")


def _submitter(c: ServerClient, stop: threading.Event, accepted: list[int], prefix: str) -> None:
    n = 0
    while not stop.is_set():
        n += 1
        try:
            accepted.append(c.submit("vision", f"{prefix}-{n}", benchmark="aido_lf")["id"])
        except ServerError:
            time.sleep(0.1)
        time.sleep(0.4)  # about as fast as the evaluators take jobs: the queue stays short


class _Evaluators:
    def __init__(self, url: str, token: str, folder: Path, lease_seconds: float, n: int) -> None:
        self.url, self.token, self.folder, self.lease = url, token, folder, lease_seconds
        self.procs: dict[int, subprocess.Popen] = {}
        self.starts = 0
        for i in range(n):
            self.start(i)

    def start(self, i: int) -> None:
        self.starts += 1
        args = [sys.executable, str(_EVALUATOR), self.url, f"e{i}", str(self.folder / f"acks-{i}.txt"),
                str(self.lease), str(self.starts)]
        env = {**os.environ, "PROXYBENCH_TOKEN": self.token,
               "PYTHONPATH": os.pathsep.join([str(_EVALUATOR.parents[1]), *sys.path])}
        log = open(self.folder / f"evaluator-{i}.log", "ab")  # noqa: SIM115 - lives with the process
        self.procs[i] = subprocess.Popen(args, env=env, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)

    def kill(self, i: int) -> None:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.procs[i].pid, signal.SIGKILL)
        self.procs[i].wait(10)

    def stop(self) -> None:
        for i in list(self.procs):
            self.kill(i)


def _posts(folder: Path) -> list[tuple[int, str, bool, bool]]:
    """(job, lease, posted late, acknowledged) of every result the evaluators posted."""
    out = []
    for f in sorted(folder.glob("acks-*.txt")):
        for line in f.read_text().splitlines():
            parts = line.split()
            if len(parts) == 4:  # a line cut by kill -9 is not a post we know the answer of
                out.append((int(parts[0]), parts[1], parts[2] == "1", parts[3] == "acknowledged"))
    return out


def _check(database_url: str, acks: list[tuple[int, str, bool]], board_rows: int, figures: RaceFigures) -> None:
    engine = create_engine(database_url)
    with engine.connect() as conn:
        results = conn.execute(text("SELECT job_id, lease_id, status, created_at FROM results")).all()
        jobs = dict(conn.execute(text("SELECT id, status FROM jobs")).all())
        leased = conn.execute(text("SELECT job_id, at FROM job_events WHERE kind IN ('leased', 'lease-lapsed')")).all()
        successes = conn.execute(text(
            "SELECT count(*) FROM jobs j JOIN submissions s ON s.id = j.submission_id "
            "WHERE j.status = 'success' AND s.status = 'active'")).scalar_one()
    engine.dispose()
    by_job: dict[int, list[tuple[str, str, float]]] = {}
    for job_id, lease_id, status, at in results:
        by_job.setdefault(job_id, []).append((lease_id, status, at))
    figures.duplicated += [f"job {j}: {len(rs)} results" for j, rs in by_job.items() if len(rs) > 1]
    acked_leases: dict[int, set[str]] = {}
    for job_id, lease_id, _late in acks:
        acked_leases.setdefault(job_id, set()).add(lease_id)
        if lease_id not in {r[0] for r in by_job.get(job_id, [])}:
            figures.lost.append(f"job {job_id}: result of lease {lease_id[:8]} acknowledged, not stored")
    figures.duplicated += [f"job {j}: {len(ls)} leases acknowledged" for j, ls in acked_leases.items() if len(ls) > 1]
    for job_id, status in jobs.items():
        stored = by_job.get(job_id, [])
        if status == "success" and not any(s == "success" for _, s, _ in stored):
            figures.disagreements.append(f"job {job_id}: status success without a success result")
        if stored and stored[0][1] != status:
            figures.disagreements.append(f"job {job_id}: status {status}, its result says {stored[0][1]}")
    for job_id, at in leased:
        stored = by_job.get(job_id)
        if stored and at > stored[0][2]:
            figures.disagreements.append(f"job {job_id}: leased or lapsed again after its result was stored")
    if board_rows != successes:
        figures.disagreements.append(f"leaderboard has {board_rows} rows, {successes} jobs succeeded")
    figures.jobs = Counter(jobs.values())
    figures.open_jobs = figures.jobs["queued"] + figures.jobs["evaluating"]


def race(database_url: str, folder: Path, *, seconds: float = 20.0, evaluators: int = 4, lease_seconds: float = 1.0,
         kill_every: float = 3.0, drain_seconds: float = 60.0, seed: int = 0) -> RaceFigures:
    """Run the race for ``seconds`` of load (then drain the queue, at most ``drain_seconds``) and check it."""
    rng = random.Random(seed)
    figures = RaceFigures()
    data = folder / "data"
    data.mkdir(parents=True)
    server = LiveServer(data, database_url, lease_seconds=lease_seconds, workers=2).start()
    t0 = time.monotonic()
    stop = threading.Event()
    accepted: list[int] = []
    evs = None
    try:
        admin = ServerClient(server.url, server.admin_token, retry_for=60.0)
        ev_token = admin.post("/users", {"name": "ev", "role": "evaluator"})["token"]
        evs = _Evaluators(server.url, ev_token, folder, lease_seconds, evaluators)
        subs = [threading.Thread(target=_submitter, args=(admin, stop, accepted, f"s{k}")) for k in range(2)]
        for t in subs:
            t.start()
        server_killed = False
        while time.monotonic() - t0 < seconds:
            time.sleep(kill_every)
            i = rng.randrange(evaluators)
            evs.kill(i)
            figures.evaluator_kills += 1
            evs.start(i)
            if not server_killed and time.monotonic() - t0 > seconds / 2:
                server.kill()  # SIGKILL, every worker process with it
                figures.server_kills += 1
                server.start()
                server_killed = True
        stop.set()
        for t in subs:
            t.join(90)
        deadline = time.monotonic() + drain_seconds
        while time.monotonic() < deadline:
            jobs = admin.get("/jobs", limit=1000)
            if not any(j["status"] in ("queued", "evaluating") for j in jobs):
                break
            time.sleep(0.5)
        evs.stop()
        time.sleep(0.2)
        board = admin.get("/leaderboards/aido_lf", limit=1)
        while board.get("stale") and time.monotonic() < deadline + 15:  # a large board is rebuilt once a second
            time.sleep(0.5)
            board = admin.get("/leaderboards/aido_lf", limit=1)
        figures.seconds = time.monotonic() - t0
        admin.close()
    finally:
        stop.set()
        if evs is not None:
            evs.stop()
        server.stop()
    posts = _posts(folder)
    acks = [(job, lease, late) for job, lease, late, ok in posts if ok]
    figures.submissions = len(accepted)
    figures.acknowledged = len(acks)
    figures.late = sum(late for _, _, late in acks)
    figures.posted_late = sum(late for _, _, late, _ in posts)
    _check(database_url, acks, board["total"], figures)
    return figures
