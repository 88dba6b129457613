"""Agents × domains × episodes → a results table, cached per episode and resumable.

Layout of a run directory::

    run.json                  what was asked (jobs, backend), for humans and for resuming
    episodes/<key>.parquet    one trajectory per finished episode
    episodes/<key>.json       its scores; written last, atomically: its presence means "done"
    results.parquet           long table: agent, domain, episode, seed, metric, value, termination

A job whose ``<key>.json`` exists is not run again, so a sweep killed at any point (Ctrl-C, a dead
worker, power loss) resumes where it stopped, and two sweeps sharing episodes share their work. A job
whose robot node failed (termination ``robot_failure``: no episode happened) is reported but not stored,
so the next run retries it.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, fields, is_dataclass, replace
from pathlib import Path

from proxybench.domain.events import Termination
from proxybench.domain.kinds import DomainKind
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import Job, JobResult, batch_group, is_privileged

__all__ = ["UNSTORED", "SweepResult", "results_frame", "run_jobs"]

#: terminations that say the episode did not happen (the plant failed): reported, never cached
UNSTORED = frozenset({Termination.ROBOT_FAILURE})


@dataclass
class SweepResult:
    """Results of a sweep (cached and new), in job order, and what it cost."""

    results: list[JobResult]
    run_dir: Path
    cached: int = 0
    ran: int = 0
    wall_s: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def _load_done(ep_dir: Path, key: str) -> JobResult | None:
    p = ep_dir / f"{key}.json"
    if not p.exists():
        return None
    try:
        res = JobResult.from_json(p.read_text())
    except (ValueError, TypeError):
        return None  # a damaged record is redone, never trusted
    if res.trajectory and not Path(res.trajectory).exists():
        return None
    return res


def _with_metrics(res: JobResult | None, metrics: Sequence[str]) -> JobResult | None:
    """A cached result that lacks some of ``metrics`` (asked for by a later run with other task metrics): scored
    from its stored trajectory, or redone (None) when there is none."""
    missing = [m for m in metrics if m not in (res.scores if res else {})]
    if res is None or not missing:
        return res
    if not res.trajectory:
        return None
    from proxybench.tasks.metrics import METRICS
    from proxybench.tasks.trajectory import Trajectory

    traj = Trajectory.load(res.trajectory)
    res.scores.update({m: float(METRICS[m](traj)) for m in missing})
    return res


def run_jobs(
    jobs: Sequence[Job],
    run_dir: str | Path,
    backend: Backend | None = None,
    *,
    progress: Callable[[int, int, JobResult | None], None] | None = None,
    keep_trajectories: bool = True,
    batch_size: int = 8,
) -> SweepResult:
    """Run every job not already done in ``run_dir``; return all results in job order.

    Jobs that can share a simulator run in batches of up to ``batch_size`` robots (smaller towards the
    end, so that no worker waits long for the last one); jobs on one robot domain run one after another on
    one node process per batch, at most ``ProtocolLink.nodes`` such processes at once (``runner.robot_jobs``).
    ``progress(done, total, result)`` is called once at the start (result None) and after each job.
    """
    backend = backend or InlineBackend()
    run_dir = Path(run_dir)
    ep_dir = run_dir / "episodes"
    ep_dir.mkdir(parents=True, exist_ok=True)
    keys = [j.key for j in jobs]  # hashing is not free: once per job
    _write_atomic(run_dir / "run.json", _run_record(jobs, keys, backend))
    by_key: dict[str, JobResult] = {}
    todo: list[Job] = []
    queued: set[str] = set()
    for job, key in zip(jobs, keys, strict=True):
        done = _with_metrics(_load_done(ep_dir, key), job.metrics)
        if done is not None:
            by_key[key] = done
        elif key not in queued:
            queued.add(key)
            todo.append(job)
    cached = len(by_key)
    t0 = time.perf_counter()
    # progress counts jobs, not keys: jobs that are the same episode (a swept value equal to the nominal θ) run
    # once and are all done then, so the count reaches the total (it stopped at 70 % of a sweep: issue 39)
    copies = Counter(keys)
    done = sum(copies[k] for k in by_key)
    if progress:
        progress(done, len(jobs), None)
    out = str(ep_dir) if keep_trajectories else None
    for res in backend.run(_batches(todo, batch_size, backend.workers), out):
        if res.termination not in UNSTORED:
            _write_atomic(ep_dir / f"{res.key}.json", res.to_json())
        done += copies[res.key] if res.key not in by_key else 0
        by_key[res.key] = res
        if progress:
            progress(done, len(jobs), res)
    results = [_as_job(by_key[k], job) for job, k in zip(jobs, keys, strict=True)]
    sweep = SweepResult(results, run_dir, cached, len(todo), time.perf_counter() - t0)
    for r in (by_key[k] for k in queued):
        for k, v in r.timings.items():
            sweep.timings[k] = sweep.timings.get(k, 0.0) + v
    frame = results_frame(results)
    tmp = run_dir / ".results.parquet.tmp"
    frame.to_parquet(tmp, index=False)
    tmp.replace(run_dir / "results.parquet")
    return sweep


def _as_job(res: JobResult, job: Job) -> JobResult:
    """``res`` under ``job``'s own domain name: jobs that are the same episode (the nominal θ and a swept value
    equal to it) share one result, and each is listed as itself in results.parquet (the nominal θ was missing)."""
    return res if res.domain == job.domain.name else replace(res, domain=job.domain.name)


def _run_record(jobs: Sequence[Job], keys: Sequence[str], backend: Backend) -> str:
    """run.json: one job per line (JSON's C encoder; an indented dump of thousands of jobs took seconds)."""
    head = json.dumps({"backend": type(backend).__name__, "workers": backend.workers})
    lines = [json.dumps(_job_record(j) | {"key": k}, default=str) for j, k in zip(jobs, keys, strict=True)]
    return head[:-1] + ', "jobs": [\n' + ",\n".join(lines) + "\n]}\n"


def _job_record(job: Job) -> dict:
    """A job as plain data (``dataclasses.asdict`` without its deep copies)."""
    out = {}
    for f in fields(job):
        v = getattr(job, f.name)
        if hasattr(v, "to_dict"):
            v = v.to_dict()
        elif is_dataclass(v):
            v = {g.name: getattr(v, g.name) for g in fields(v)}
        out[f.name] = v
    return out


def _batches(todo: Sequence[Job], batch_size: int, workers: int) -> list[list[Job]]:
    """Group jobs by :func:`batch_group` and cut the groups into batches of at most ``batch_size``, costliest
    first and smaller towards the end (guided self-scheduling: a batch takes about 1/(2·workers) of the work
    left), so that every worker finishes at about the same time.

    Cost estimate per job: seconds, ten times that for camera agents (rendering dominates). Robot domains
    come first, in whole batches (a node start per batch; a real robot runs in real time, so the rest of the
    work can go on beside it).
    """
    groups: dict[tuple, list[Job]] = {}
    for job in todo:
        groups.setdefault(batch_group(job), []).append(job)

    def cost(job: Job) -> float:
        return max(job.duration, 1e-3) * (1.0 if is_privileged(job.agent) else 10.0)

    out = [jobs[i : i + batch_size] for g, jobs in groups.items() if g[0] == DomainKind.ROBOT
           for i in range(0, len(jobs), batch_size)]
    ordered = sorted((jobs for g, jobs in groups.items() if g[0] != DomainKind.ROBOT), key=lambda jobs: -cost(jobs[0]))
    left = sum(cost(jobs[0]) * len(jobs) for jobs in ordered)
    for jobs in ordered:
        c = cost(jobs[0])
        i = 0
        while i < len(jobs):
            size = max(1, min(batch_size, len(jobs) - i, math.ceil(left / (2 * max(1, workers) * c))))
            out.append(jobs[i : i + size])
            i += size
            left -= size * c
    return out


def results_frame(results: Sequence[JobResult]):
    """Long pandas table: one row per (agent, domain, episode, metric)."""
    import pandas as pd

    rows = [
        {"agent": r.agent, "domain": r.domain, "episode": r.episode, "seed": r.seed, "metric": m, "value": v,
         "termination": r.termination, "key": r.key}
        for r in results
        for m, v in r.scores.items()
    ]
    return pd.DataFrame(rows, columns=["agent", "domain", "episode", "seed", "metric", "value", "termination", "key"])
