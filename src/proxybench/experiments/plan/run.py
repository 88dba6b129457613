"""Sample-size planning as a study: a pilot on the target (optionally a sequential allocation), candidate
proxies replaying it, then what n target episodes per agent would give (:mod:`proxybench.usefulness.plan`):
pairs within the task's tolerance ε are ties, and every count is a range over the pilot's posterior.

The pilot runs (or is read) through the target like every study's target episodes, cached in the run
directory, so ``predictivity`` with the same run directory re-uses them; ``plan.sequential`` spends
``plan.budget`` more target episodes where they settle most (:mod:`proxybench.experiments.plan.sequential`).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from proxybench.experiments.config import COMMAND_DEFAULTS, ConfigError, Experiment, ExperimentConfig, resolve
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.targets.base import TargetRun

__all__ = ["PlanResult", "run_plan", "tolerances", "write_plan"]

Progress = Callable[[str, int, int], None]


@dataclass
class PlanResult:
    """The plan (``usefulness.plan.Plan``), the target's episodes it came from and, if run, the sequential loop."""

    plan: Any
    target: TargetRun
    experiment: Experiment
    sequential: Any = None  # experiments.sequential.SequentialResult
    wall_s: float = 0.0


def run_plan(cfg: ExperimentConfig, out: str | Path, backend: Backend | None = None, progress: Progress | None = None,
             *, quick: bool = False) -> PlanResult:
    """Run (or read) the pilot, the sequential allocation if asked and the candidate proxies (``sweep`` given),
    then plan; target and proxy episodes are cached in ``out/runs``."""
    from proxybench.experiments.predictivity.run import proxy_domains, proxy_jobs
    from proxybench.runner.sweep import run_jobs
    from proxybench.targets.base import by_agent
    from proxybench.tasks.metrics import METRICS
    from proxybench.usefulness.plan import DEFAULT_GRID, plan

    t0 = time.perf_counter()
    out, backend, p = Path(out), backend or InlineBackend(), cfg.plan
    defaults = COMMAND_DEFAULTS[("plan", quick)]
    exp, target = resolve(cfg, "plan", quick=quick, work_dir=out / "agents")
    if exp.episode_count < 2:
        raise ConfigError(f"episodes: the pilot needs at least 2 episodes per agent, got {exp.episode_count}")
    tol = tolerances(exp.metrics, exp.seconds, p.tolerance)
    run_kw = dict(map_name=exp.map, seconds=exp.seconds, seed=exp.seed, metrics=exp.metrics,
                  image_size=exp.image_size, run_dir=out / "runs", backend=backend, progress=progress)
    seq = None
    if p.sequential:
        from proxybench.experiments.plan.sequential import run_sequential

        if not isinstance(exp.episodes, int):
            raise ConfigError("episodes: the sequential plan's pilot is a count (it adds the next ids), got ids")
        seq = run_sequential(target, exp.agents, pilot=exp.episodes, budget=p.budget or defaults["budget"],
                             batch=p.batch, tolerances=tol, **run_kw)
        tgt = seq.run
    else:
        tgt = target.run(exp.agents, episodes=exp.episodes, **run_kw)
    proxies = {}
    if "sweep" in cfg.model_fields_set:  # candidates only where asked for
        for _, _, dom in proxy_domains(exp):
            jobs = proxy_jobs(exp, tgt, dom)
            proxies[dom.name] = by_agent(jobs, run_jobs(jobs, out / "runs", backend).results, exp.metrics)
    higher = tuple(METRICS[m].higher_is_better for m in exp.metrics)
    grid = [n for n in DEFAULT_GRID if n <= p.max_episodes] + ([p.max_episodes] if p.max_episodes not in DEFAULT_GRID
                                                                else [])
    made = plan(tgt.results, higher, exp.metrics, proxies=proxies, width=p.width, p_correct=p.p_correct,
                confidence=p.confidence, grid=grid, reps=p.reps or defaults["reps"], power=p.power, batch=p.batch,
                seed=exp.seed, tolerances=tol, range_level=p.range_level, uncertain=not p.pilot_as_truth)
    return PlanResult(made, tgt, exp, seq, time.perf_counter() - t0)


def tolerances(metrics: tuple[str, ...], seconds: float, given: dict[str, float]) -> tuple[float, ...]:
    """ε per metric: AIDO's semiorder tolerances at this episode length, with the experiment's own (``given``)."""
    from proxybench.usefulness.indifference import semiorder_tolerances

    unknown = sorted(set(given) - set(metrics))
    if unknown:
        raise ConfigError(f"plan.tolerance: {', '.join(unknown)}: not a metric of this plan ({', '.join(metrics)})")
    bad = [k for k, v in given.items() if not (math.isfinite(v) and v >= 0)]
    if bad:
        raise ConfigError(f"plan.tolerance: {', '.join(bad)}: a tolerance is a number >= 0")
    return semiorder_tolerances(metrics, seconds, overrides=dict(given))


def write_plan(res: PlanResult, out: str | Path) -> list[Path]:
    """plan.json (with the sequential rounds), plan.csv, pairs.csv and plan.png (+ .svg) in ``out``."""
    import pandas as pd

    from proxybench.experiments.predictivity.report import plot_plan

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    p, seq = res.plan, res.sequential
    data = {"target": res.target.info.statement, "wall_s": round(res.wall_s, 1), **p.to_dict()}
    if seq is not None:
        data["sequential"] = {"episodes": seq.episodes, "stopped": seq.stopped, "looks": seq.looks,
                              "open_after_pilot": seq.open_after_pilot, "rounds": [asdict(b) for b in seq.history],
                              "decisions": [{"a": a, "b": b, "decision": d} for (a, b), d in seq.decisions.items()]}
    (out / "plan.json").write_text(json.dumps(data, indent=1, default=str))
    pd.DataFrame([r.__dict__ for r in p.rows]).to_csv(out / "plan.csv", index=False)
    pd.DataFrame([q.__dict__ for q in p.pairs]).to_csv(out / "pairs.csv", index=False)
    png = plot_plan(p, out / "plan.png", res.target.info.label)
    return [out / "plan.json", out / "plan.csv", out / "pairs.csv", png]
