"""From an evaluation to what the server stores: checked data, scores, a per-episode report, artifact files.

The scores are the aggregated columns of :func:`proxybench.tasks.aggregate.aggregate` (``<metric>_<stat>``,
the names a benchmark's ``scoring`` uses), JSON-clean (NaN and ±inf become null). Before anything is
reported the data are checked (:func:`check_data`): every episode present, its trajectory readable,
finite, as long as the benchmark says unless it ended early for a reason, and free of events that
invalidate a run. A failed check is never the agent's fault: it is the evaluator's (simulation) or the
host's (a target).
"""

from __future__ import annotations

import math
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.runner.evaluate import Evaluation
from proxybench.tasks.trajectory import TERMINATIONS, Termination, Trajectory, TrajectoryError

__all__ = ["INVALIDATING_EVENTS", "SplitSummary", "check_data", "clean", "pack_trajectories", "summarize",
           "topdown_video"]

#: event kinds after which an episode cannot be scored: a target that lost track of the robot, needed a
#: human hand, or had a fault of its own
INVALIDATING_EVENTS = frozenset({"invalid", Termination.ROBOT_FAILURE, "tracking_lost", "manual_intervention"})
_MAX_EVENTS = 20


def clean(value: Any) -> float | None:
    """A JSON-safe score: a finite float, or None for NaN / ±inf / missing."""
    try:
        x = float(value)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


@dataclass
class SplitSummary:
    """One split (validation or hidden test) of one job: scores, report, and what went wrong."""

    split: str
    scores: dict[str, float | None]
    report: dict[str, Any]
    problems: list[str] = field(default_factory=list)  # invalid data: the evaluator's or the host's fault
    failures: list[dict[str, Any]] = field(default_factory=list)  # agent failures: the submission's fault

    def failure_message(self) -> str:
        """One line per failed episode, with the node's last stderr lines (its traceback) once."""
        n = len(self.report.get("episodes", []))
        lines = [f"the agent failed in {len(self.failures)} of {n} {self.split} episodes:"]
        for f in self.failures:
            code = f" (exit code {f['exit_code']})" if f.get("exit_code") is not None else ""
            lines.append(f"  episode {f['episode']}: {f['reason']}: {f['message']}{code}")
        tail = next((f["stderr_tail"] for f in self.failures if f.get("stderr_tail")), None)
        if tail:
            lines.append("last lines the agent wrote to stderr:")
            lines += ["  " + line for line in tail[-15:]]
        return "\n".join(lines)


def _load(path: str | None) -> tuple[Trajectory | None, str | None]:
    if not path:
        return None, "no trajectory was written"
    try:
        return Trajectory.load(path), None
    except (TrajectoryError, OSError) as exc:
        return None, f"trajectory unreadable ({exc})"


def check_data(ev: Evaluation) -> list[str]:
    """Problems that make the evaluation's data unusable (empty list: the data are complete and valid)."""
    bench = ev.benchmark
    specs = bench.episode_specs()
    got = {r.episode: r for r in ev.sweep.results}
    problems = [f"episode {s.index}: no result" for s in specs if s.index not in got]
    if len(ev.sweep.results) != len(specs):
        problems.append(f"{len(ev.sweep.results)} results for {len(specs)} episodes")
    frame_dt = 1.0 / bench.frame_rate
    for r in ev.sweep.results:
        where = f"episode {r.episode}"
        if r.termination not in TERMINATIONS:
            problems.append(f"{where}: unknown termination {r.termination!r}")
        traj, error = _load(r.trajectory)
        if traj is None:
            if r.termination is not Termination.AGENT_FAILURE or r.trajectory:  # a refused agent has none, rightly
                problems.append(f"{where}: {error}")
            continue
        pose = traj.pose()
        if pose.size == 0 or not np.all(np.isfinite(pose)) or not np.all(np.isfinite(traj["t"])):
            problems.append(f"{where}: the trajectory has missing or non-finite samples")
        if r.termination is Termination.TIMEOUT and traj.duration < bench.duration - 1.5 * frame_dt:
            problems.append(f"{where}: ended after {traj.duration:.2f} s of {bench.duration:g} s without a reason "
                            "(incomplete episode)")
        bad = next((e for e in traj.events if e.kind in INVALIDATING_EVENTS), None)
        if bad is not None:
            problems.append(f"{where}: invalidating event {str(bad.kind)!r} at t={bad.t}: {bad.message}")
    return problems


def _episode_row(r: Any) -> tuple[dict[str, Any], dict[str, Any] | None]:
    traj, _ = _load(r.trajectory)
    row: dict[str, Any] = {
        "episode": r.episode, "termination": r.termination,
        "duration": clean(traj.duration) if traj is not None else None,
        "scores": {k: clean(v) for k, v in r.scores.items()},
        "events": [replace(e, stderr_tail=()).to_dict() for e in traj.events[:_MAX_EVENTS]] if traj else [],
        "message": r.message, "seed": r.seed,
    }
    failure = None
    if r.termination is Termination.AGENT_FAILURE:
        ev = traj.failure if traj is not None else None
        failure = {"episode": r.episode, "reason": str(Termination.AGENT_FAILURE), "message": r.message,
                   "exit_code": None, "stderr_tail": []}
        if ev is not None:
            failure.update(reason=ev.reason or failure["reason"], message=ev.message, exit_code=ev.exit_code,
                           stderr_tail=list(ev.stderr_tail))
    return row, failure


def summarize(ev: Evaluation, split: str, *, domain_kind: str, extra: dict[str, Any] | None = None) -> SplitSummary:
    """Scores and report of one split; runs :func:`check_data`."""
    from proxybench.tasks.aggregate import scores_by_agent

    problems = check_data(ev)
    rows, failures = [], []
    for r in sorted(ev.sweep.results, key=lambda r: r.episode):
        row, failure = _episode_row(r)
        rows.append(row)
        if failure is not None:
            failures.append(failure)
    by_agent = scores_by_agent(ev.aggregates) if len(ev.aggregates) else {}
    raw = next(iter(by_agent.values()), {})
    scores = {k: clean(v) for k, v in raw.items()}
    for c in ev.benchmark.criteria():
        scores.setdefault(c.metric, None)
    report = {
        "split": split, "benchmark": ev.benchmark.name, "domain_kind": domain_kind,
        "episodes": rows, "terminations": _count(r["termination"] for r in rows),
        "agent_failures": failures, "criteria": [c.metric for c in ev.benchmark.criteria()],
        "timings": {k: clean(v) for k, v in ev.sweep.timings.items()}, "wall_s": clean(ev.sweep.wall_s),
        **(extra or {}),
    }
    if problems:
        report["data_problems"] = problems
    return SplitSummary(split, scores, report, problems, failures)


def _count(items: Any) -> dict[str, int]:
    out: dict[str, int] = {}
    for x in items:
        out[x] = out.get(x, 0) + 1
    return out


def pack_trajectories(ev: Evaluation, path: Path) -> Path:
    """One zip: ``episode-<k>.parquet`` per episode (proxybench trajectories, readable with pyarrow alone)
    and ``results.parquet`` (the long score table)."""
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_STORED) as zf:  # Parquet is compressed already
        for r in sorted(ev.sweep.results, key=lambda r: r.episode):
            if r.trajectory and Path(r.trajectory).is_file():
                zf.write(r.trajectory, f"episode-{r.episode}.parquet")
        results = ev.sweep.run_dir / "results.parquet"
        if results.is_file():
            zf.write(results, "results.parquet")
    return path


def topdown_video(trajectory: str | Path, path: Path, fps: float, *, max_seconds: float = 30.0) -> Path:
    """A short top-down MP4 of a recorded episode (redrawn from its poses: the agent is not run again)."""
    from proxybench.domain.maps import load_map
    from proxybench.domain.topdown import top_down
    from proxybench.media import VideoWriter

    traj = Trajectory.load(trajectory)
    m = load_map(traj.meta["map"])
    t, pose = traj["t"], traj.pose()
    times = np.arange(t[0], min(t[-1], t[0] + max_seconds) + 1e-9, 1.0 / fps)
    idx = np.clip(np.searchsorted(t, times), 0, len(t) - 1)
    px = max(48, min(160, 640 // max(m.width, m.height)))
    with VideoWriter(path, fps) as writer:
        for k in idx:
            writer.append(top_down(m, pose[k : k + 1], px_per_tile=px))
    return path
