"""Score one simulator θ against a target, and compare it with another θ on the same episodes.

The question a user has after reading a paper or an optimisation: "is *this* θ any good on *my* target, and is
it better than what I use now?". Every θ replays the target's episodes (same agents, ids, seeds and start
poses: :func:`proxybench.experiments.predictivity.run.proxy_jobs`), so the two are compared on paired resamples of
the same episodes (:func:`proxybench.usefulness.noise.compare_paired`), not by eyeing two intervals. The
nominal calibration (doing nothing) and the no-simulator baselines are always scored beside them, and the
target's own noise floor says how low PRPV can go with this many episodes.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.experiments.baselines import NOMINAL, baselines
from proxybench.experiments.config import Experiment, ExperimentConfig, resolve
from proxybench.experiments.predictivity.run import proxy_jobs
from proxybench.experiments.proxies import proxy_domain, proxy_params
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import DomainSpec
from proxybench.runner.sweep import run_jobs
from proxybench.targets.base import Target, TargetRun, by_agent
from proxybench.tasks.metrics import METRICS
from proxybench.usefulness.intervals import Usefulness, usefulness
from proxybench.usefulness.metrics import Estimate, PairedResults
from proxybench.usefulness.noise import PairedComparison, compare_paired, noise_floor, paired_prpv_samples

__all__ = ["ProxyScore", "ScoreResult", "measure_score", "score_proxy"]

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class ProxyScore:
    """One θ's figures against the target: its label, the θ on top of the nominal calibration, its usefulness."""

    label: str
    theta: dict[str, Any]
    figures: Usefulness


@dataclass
class ScoreResult:
    """θ, the θ it is compared with, the nominal calibration and the baselines; ΔPRPV(θ − versus) paired."""

    experiment: Experiment
    target: TargetRun
    scored: ProxyScore
    versus: ProxyScore
    comparison: PairedComparison  # PRPV(scored) − PRPV(versus)
    versus_nominal: PairedComparison | None  # PRPV(scored) − PRPV(nominal), when versus is another θ
    baselines: dict[str, Usefulness]
    noise: Estimate
    proxy_episodes: int

    def to_dict(self) -> dict[str, Any]:
        def figures(u: Usefulness) -> dict[str, Any]:
            return {k: {"value": e.value, "low": e.low, "high": e.high} for k, e in u.items()}

        def delta(c: PairedComparison | None) -> dict[str, Any] | None:
            return None if c is None else {"a": c.a, "b": c.b, "delta": c.delta.value, "low": c.delta.low,
                                           "high": c.delta.high, "separated": c.separated, "method": c.delta.method}

        return {"experiment": self.experiment.to_dict(), "target": self.target.info.statement,
                "target_kind": str(self.target.info.kind),
                "episodes_per_agent": self.experiment.episode_count, "agents": list(self.target.results),
                "scored": {"label": self.scored.label, "theta": self.scored.theta, **figures(self.scored.figures)},
                "versus": {"label": self.versus.label, "theta": self.versus.theta, **figures(self.versus.figures)},
                "comparison": delta(self.comparison), "versus_nominal": delta(self.versus_nominal),
                "baselines": {k: figures(u) for k, u in self.baselines.items()},
                "noise_floor": {"value": self.noise.value, "low": self.noise.low, "high": self.noise.high},
                "proxy_episodes_simulated": self.proxy_episodes}


def score_proxy(cfg: ExperimentConfig, theta: Mapping[str, Any], run_dir: str | Path, *,
                versus: Mapping[str, Any] | None = None, backend: Backend | None = None,
                progress: Progress | None = None, quick: bool = False, target: Target | None = None) -> ScoreResult:
    """Score ``theta`` against the config's target; compare it with ``versus`` (default: the nominal θ).

    Episodes are cached in ``run_dir`` (shared with ``predictivity``/``optimize`` runs of the same target).
    """
    backend = backend or InlineBackend()
    run_dir = Path(run_dir)
    exp, target = resolve(cfg, "predictivity", quick=quick, work_dir=run_dir.parent / "agents", target=target)
    doms = {"param": proxy_domain(exp.image_size, exp.proxy, theta, "param", NOMINAL),
            "vs_param": proxy_domain(exp.image_size, exp.proxy, versus or {}, "vs_param", NOMINAL),
            NOMINAL: DomainSpec(NOMINAL, proxy_params(exp.image_size, exp.proxy))}
    # θ compared with itself (the nominal θ scored, a θ list that holds the θ compared with) is a valid question:
    # both replay the same episodes (one cached set), so the paired difference is 0 [0, 0]
    tgt = target.run(exp.agents, map_name=exp.map, seconds=exp.seconds, episodes=exp.episodes, seed=exp.seed,
                     metrics=exp.metrics, image_size=exp.image_size, run_dir=run_dir, backend=backend,
                     progress=progress)
    unique = {d.name: d for d in doms.values()}  # nominal may be the θ compared with
    jobs = {name: proxy_jobs(exp, tgt, d) for name, d in unique.items()}
    flat = [j for js in jobs.values() for j in js]
    sweep = run_jobs(flat, run_dir, backend,
                     progress=(lambda done, total, _r: progress("proxy episodes", done, total)) if progress else None)
    results = iter(sweep.results)
    proxies = {name: by_agent(js, [next(results) for _ in js], exp.metrics) for name, js in jobs.items()}
    return measure_score(exp, tgt, proxies, doms["param"].name, dict(theta), doms["vs_param"].name, dict(versus or {}),
                         sweep.ran)


def measure_score(exp: Experiment, tgt: TargetRun, proxies: Mapping[str, dict[str, np.ndarray]], scored: str,
                  theta: dict[str, Any], versus_label: str, versus: dict[str, Any],
                  proxy_episodes: int = 0) -> ScoreResult:
    """The figures of θ (``proxies[scored]``) and of the θ it is compared with (``proxies[versus_label]``) against
    the target, paired, beside the nominal calibration (``proxies[NOMINAL]``) and the baselines. Runs no episode."""
    higher = tuple(METRICS[m].higher_is_better for m in exp.metrics)

    base = baselines(tgt, proxies[NOMINAL], higher, exp.metrics, n_boot=exp.n_boot, seed=exp.seed)

    def figures(name: str) -> Usefulness:  # the nominal θ's are the baselines' (same resamples): computed once
        return base[NOMINAL] if name == NOMINAL else usefulness(
            PairedResults(proxies[name], tgt.results, higher, exp.metrics), n_boot=exp.n_boot, seed=exp.seed)

    a = ProxyScore(scored, theta, figures(scored))
    b = ProxyScore(versus_label, versus, figures(versus_label))
    names = [a.label, b.label] + ([NOMINAL] if NOMINAL not in (a.label, b.label) else [])
    samples = paired_prpv_samples(tgt.results, [proxies[n] for n in names], higher, n_boot=exp.n_boot, seed=exp.seed)
    points = [a.figures["prpv"].value, b.figures["prpv"].value, base[NOMINAL]["prpv"].value][: len(names)]
    vs_nominal = compare_paired(names, points, samples, 0, 2) if len(names) == 3 else None
    return ScoreResult(exp, tgt, a, b, compare_paired(names, points, samples, 0, 1), vs_nominal, base,
                       noise_floor(tgt.results, higher, n_boot=exp.n_boot, seed=exp.seed), proxy_episodes)
