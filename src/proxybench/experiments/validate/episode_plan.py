"""How many target episodes per agent a validation study needs: ``plan`` run on a finished study's own episodes.

A validation study fixes E1 (episodes per tuning agent) and E2 (per held-out agent) before it runs. Its shipped
per-episode table (``results/NAME/episodes.csv.gz``: every agent's episodes on every target, and every grid
candidate's replays of them) is a pilot on each target, so the planner (:func:`proxybench.usefulness.plan.plan`,
docs/usefulness.md) can say, per target, what n episodes per agent would have bought: the chance that PRPV over
the grid picks the world's best candidate, and the width of PRPV's order range — each over worlds drawn from the
posterior given the pilot, never taking the pilot as the truth. No episode runs.

Every agent of the target is in its pilot (tuning agents with their E1 episodes, held-out ones with their E2: the
same target, other seeds); the candidates are the grid's (the continuous picks replayed only the held-out half).
The tolerances are the study's, from ``criteria.json``. Widths are in PRPV/K(K−1), the study's unit.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict

from proxybench.experiments.config import ConfigError

__all__ = ["EpisodePlan", "TargetPlan", "plan_study", "write_episode_plan"]

Progress = Callable[[str, int, int], None]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class TargetPlan(_Model):
    """One target's pilot, planned."""

    target: int
    agents: int
    candidates: int
    pilot_episodes: int
    p_correct_at_pilot: float
    """P(PRPV over the grid picks the world's best candidate) with the study's episodes per agent"""
    n_for_p_correct: int | None
    """episodes per agent for that chance to reach the goal (None: not within the planned grid)"""
    width_at_pilot: float
    """mean width of PRPV's order range in PRPV/K(K−1), with the study's episodes per agent"""
    n_for_width: int | None
    rows: list[tuple[int, float, float]]
    """(n, P(right θ), mean width in PRPV/K(K−1)) at each planned n"""


class EpisodePlan(_Model):
    """episode_plan.json: the goals, each target's plan, and the medians over targets with their spread."""

    study: str
    p_correct_goal: float
    width_goal: float
    reps: int
    seed: int
    episodes_tune: int
    episodes_eval: int
    targets: list[TargetPlan]
    median_p_correct_at_pilot: float
    median_n_for_p_correct: float | None
    """median over targets (a target whose n is beyond the grid counts as beyond: None if half are)"""
    quartiles_n_for_p_correct: tuple[float | None, float | None]
    median_width_at_pilot: float
    median_n_for_width: float | None


def _criteria(folder: Path) -> dict:
    path = folder / "criteria.json"
    try:
        return json.loads(path.read_text())["settings"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{path}: not a validation study's criteria ({type(exc).__name__}: {exc})") from None


def _table(folder: Path):
    import pandas as pd

    path = folder / "episodes.csv.gz"
    if not path.is_file():
        raise ConfigError(f"{path}: no per-episode table (a study exported with `proxybench results export`)")
    df = pd.read_csv(path)
    missing = {"target", "role", "candidate", "agent", "episode"} - set(df.columns)
    if missing:
        raise ConfigError(f"{path}: columns {', '.join(sorted(missing))} missing")
    return df


def _pilot(df, metrics: list[str], grid_size: int) -> tuple[dict, dict]:
    """(the target's episodes per agent, each grid candidate's replays per agent), rows in episode order."""
    def per_agent(rows) -> dict[str, np.ndarray]:
        return {a: g.sort_values("episode")[metrics].to_numpy(float) for a, g in rows.groupby("agent")}

    drives = df["agent"].astype(str).str.startswith("calib-")  # the calibration's drives are not agents
    target = per_agent(df[(df["role"] != "candidate") & ~drives])  # the target's own runs ("target" or "other")
    cands = df[(df["role"] == "candidate") & (df["candidate"] < grid_size)]
    proxies = {f"candidate {c}": per_agent(g) for c, g in cands.groupby("candidate")}
    return target, proxies


def _n_at(rows: list, goal: Callable) -> int | None:
    return next((r.n for r in rows if goal(r)), None)


def plan_study(folder: str | Path, *, p_correct: float = 0.8, width: float = 0.05, reps: int = 100, seed: int = 0,
               targets: int | None = None, progress: Progress | None = None) -> EpisodePlan:
    """Plan every target of the study in ``folder`` (its first ``targets`` only, when given)."""
    from proxybench.tasks.metrics import METRICS
    from proxybench.usefulness.plan import plan

    folder = Path(folder)
    s = _criteria(folder)
    metrics = list(s["metrics"])
    higher = tuple(METRICS[m].higher_is_better for m in metrics)
    tol = tuple(float(s["tolerances"][m]) for m in metrics)
    grid_size = math.prod(len(v) for v in s["grid"].values())
    df = _table(folder)
    ids = sorted(df["target"].unique())[:targets]
    out = []
    for i, k in enumerate(ids):
        pilot, proxies = _pilot(df[df["target"] == k], metrics, grid_size)
        scale = len(pilot) * (len(pilot) - 1)  # PRPV → PRPV/K(K−1)
        made = plan(pilot, higher, tuple(metrics), proxies=proxies, width=width * scale, p_correct=p_correct,
                    reps=reps, seed=seed + int(k), tolerances=tol)
        first = made.rows[0]
        out.append(TargetPlan(
            target=int(k), agents=len(pilot), candidates=len(proxies), pilot_episodes=first.n,
            p_correct_at_pilot=first.p_correct, n_for_p_correct=made.n_for_p_correct,
            width_at_pilot=first.width_mean / scale, n_for_width=made.n_for_width,
            rows=[(r.n, r.p_correct, r.width_mean / scale) for r in made.rows]))
        if progress:
            progress("targets planned", i + 1, len(ids))
    if not out:
        raise ConfigError(f"{folder}: no target in the per-episode table")
    return _summarize(folder.name, out, s, p_correct=p_correct, width=width, reps=reps, seed=seed)


def _median_n(values: list[int | None], q: float = 50.0) -> float | None:
    """A percentile of the n's where a target beyond the grid counts as infinitely many (None if it lands there)."""
    v = np.percentile([math.inf if n is None else n for n in values], q, method="inverted_cdf")
    return None if not math.isfinite(v) else float(v)


def _summarize(name: str, plans: list[TargetPlan], s: dict, **goals) -> EpisodePlan:
    n_p = [t.n_for_p_correct for t in plans]
    return EpisodePlan(
        study=name, p_correct_goal=goals["p_correct"], width_goal=goals["width"], reps=goals["reps"],
        seed=goals["seed"], episodes_tune=int(s["episodes_tune"]), episodes_eval=int(s["episodes_eval"]),
        targets=plans, median_p_correct_at_pilot=float(np.median([t.p_correct_at_pilot for t in plans])),
        median_n_for_p_correct=_median_n(n_p), quartiles_n_for_p_correct=(_median_n(n_p, 25), _median_n(n_p, 75)),
        median_width_at_pilot=float(np.median([t.width_at_pilot for t in plans])),
        median_n_for_width=_median_n([t.n_for_width for t in plans]))


def write_episode_plan(result: EpisodePlan, out: str | Path) -> list[Path]:
    """episode_plan.json and episode_plan.csv (one row per target) in ``out``."""
    import csv

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    js = out / "episode_plan.json"
    js.write_text(result.model_dump_json(indent=1))
    path = out / "episode_plan.csv"
    with path.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["target", "agents", "candidates", "pilot_episodes", "p_correct_at_pilot", "n_for_p_correct",
                    "width_at_pilot", "n_for_width"])
        for t in result.targets:
            w.writerow([t.target, t.agents, t.candidates, t.pilot_episodes, f"{t.p_correct_at_pilot:.4g}",
                        t.n_for_p_correct if t.n_for_p_correct is not None else "", f"{t.width_at_pilot:.4g}",
                        t.n_for_width if t.n_for_width is not None else ""])
    return [js, path]
