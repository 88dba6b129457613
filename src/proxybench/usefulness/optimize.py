"""Proxy optimisation: θ* = argmin PRPV (or PPV, or a mix) over a subset of simulator parameters.

Each Optuna trial proposes θ, the runner evaluates the agents in that proxy (cached, so repeated θ
cost nothing, and Ray works), and the objective compares the proxy's results with the target's.
Studies live in memory, in SQLite (default when a path is given) or in any SQLAlchemy database such as
PostgreSQL, so many workers can share one study.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.domain.params import DomainParams
from proxybench.domain.reality import TRUTH, reality_params
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job, JobResult
from proxybench.runner.sweep import run_jobs
from proxybench.tasks.metrics import METRICS
from proxybench.usefulness.metrics import PairedResults, dominance, ppv_value, prpv_value

__all__ = ["OBJECTIVES", "OptimizeConfig", "OptimizeResult", "optimize_proxy"]

OBJECTIVES = ("prpv", "ppv", "mix")


@dataclass
class OptimizeConfig:
    """What to search, how, and on which workload."""

    space: dict[str, tuple[float, float]] = field(default_factory=lambda: {
        "trim": (-0.3, 0.3), "camera_pitch": (12.0, 26.0)})
    objective: str = "mix"
    n_trials: int = 60
    sampler: str = "tpe"
    storage: str | None = None
    study_name: str = "proxybench-proxy"
    agents: tuple[str, ...] = ("straight", "bang-bang", "pid", "pid-fast", "pid-twitchy", "pure-pursuit", "vision",
                               "vision-fast", "vision-pitch25", "vision-twitchy", "vision-slow", "pid-sluggish")
    episodes: int = 4
    seconds: float = 20.0
    map: str = "loop_3x3"
    image_size: tuple[int, int] = (160, 120)
    metrics: tuple[str, ...] = ("driven_lanedir_consec", "survival_time")
    seed: int = 0

    def __post_init__(self) -> None:
        if self.objective not in OBJECTIVES:
            raise ValueError(f"objective must be one of {OBJECTIVES}, got {self.objective!r}")
        if self.sampler not in ("tpe", "gp", "random"):
            raise ValueError(f"sampler must be tpe, gp or random, got {self.sampler!r}")
        for name, (lo, hi) in self.space.items():
            if name not in DomainParams.model_fields:
                raise ValueError(f"space: unknown domain parameter {name!r}")
            if not lo < hi:
                raise ValueError(f"space: {name} needs low < high, got [{lo}, {hi}]")


@dataclass
class OptimizeResult:
    """θ* and its objective value (the residual gap), the truth beside it, and the study.

    Each trial's objective is itself an estimate from a few episodes per agent, so the single best trial
    is partly luck; ``recovered`` is the mean θ of the best decile of trials (at least 3), a consensus
    that the noise of one evaluation cannot drag away. ``best_params`` is the single best trial.
    """

    best_params: dict[str, float]
    best_value: float
    truth: dict[str, float]
    study: Any
    trials: list[dict[str, Any]]
    recovered: dict[str, float] = field(default_factory=dict)

    def errors(self) -> dict[str, float]:
        return {k: v - self.truth[k] for k, v in self.recovered.items() if k in self.truth}


def best_decile(trials: list[dict[str, Any]], names: list[str]) -> dict[str, float]:
    """Mean θ of the best tenth of the trials (at least 3, at most all)."""
    ranked = sorted((t for t in trials if t.get("value") is not None), key=lambda t: t["value"])
    top = ranked[: max(3, len(ranked) // 10)]
    return {n: float(np.mean([t[n] for t in top])) for n in names} if top else {}


def _by_agent(results: list[JobResult], metrics: tuple[str, ...]) -> dict[str, np.ndarray]:
    by: dict[str, list[list[float]]] = {}
    for r in results:
        by.setdefault(r.agent, []).append([r.scores[m] for m in metrics])
    return {a: np.asarray(v) for a, v in by.items()}


def _objective_value(kind: str, proxy: Mapping[str, np.ndarray], target: Mapping[str, np.ndarray],
                     higher: tuple[bool, ...]) -> tuple[float, dict[str, float]]:
    pr = PairedResults(dict(proxy), dict(target), higher)
    k = len(pr.agents)
    prpv = prpv_value(dominance(pr.proxy, higher), dominance(pr.target, higher))
    ppv = ppv_value(pr.proxy, pr.target)
    norm_prpv, norm_ppv = prpv / max(k * (k - 1), 1), ppv / max(k * len(higher), 1)
    value = {"prpv": prpv, "ppv": ppv, "mix": norm_prpv + norm_ppv}[kind]
    return value, {"prpv": prpv, "ppv": ppv}


def _is_count(name: str) -> bool:
    """An integer domain parameter (e.g. ``extra_duckies``): Optuna proposes whole numbers for it."""
    field = DomainParams.model_fields.get(name)
    return field is not None and field.annotation is int


def _sampler(cfg: OptimizeConfig):
    import optuna

    if cfg.sampler == "gp":
        return optuna.samplers.GPSampler(seed=cfg.seed)
    if cfg.sampler == "random":
        return optuna.samplers.RandomSampler(seed=cfg.seed)
    return optuna.samplers.TPESampler(seed=cfg.seed, n_startup_trials=min(10, cfg.n_trials))


def optimize_proxy(
    cfg: OptimizeConfig, run_dir: str | Path, backend: Backend | None = None,
    progress: Callable[[int, int, float], None] | None = None,
) -> OptimizeResult:
    """Search ``cfg.space`` for the proxy θ whose verdicts best match the target (the reality model)."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    backend = backend or InlineBackend()
    w, h = cfg.image_size
    higher = tuple(METRICS[m].higher_is_better for m in cfg.metrics)

    def jobs_for(dom: DomainSpec) -> list[Job]:
        return [Job(AgentSpec(a), dom, cfg.map, e, cfg.seed * 10_000 + e, cfg.seconds, metrics=cfg.metrics)
                for a in cfg.agents for e in range(cfg.episodes)]

    target_dom = DomainSpec("reality", reality_params(image_width=w, image_height=h).model_dump(), "reality-model")
    target = _by_agent(run_jobs(jobs_for(target_dom), run_dir, backend).results, cfg.metrics)

    def objective(trial) -> float:
        theta = {name: trial.suggest_int(name, int(lo), int(hi)) if _is_count(name)
                 else trial.suggest_float(name, lo, hi) for name, (lo, hi) in cfg.space.items()}  # counts are ints
        params = DomainParams(image_width=w, image_height=h, **{**TRUTH, **theta})
        dom = DomainSpec("proxy " + " ".join(f"{k}={v:.4g}" for k, v in theta.items()), params.model_dump())
        proxy = _by_agent(run_jobs(jobs_for(dom), run_dir, backend).results, cfg.metrics)
        value, parts = _objective_value(cfg.objective, proxy, target, higher)
        for k, v in parts.items():
            trial.set_user_attr(k, v)
        if progress:
            progress(trial.number + 1, cfg.n_trials, value)
        return value

    storage = cfg.storage
    if storage and "://" not in storage:
        storage = f"sqlite:///{Path(storage).resolve()}"
    study = optuna.create_study(direction="minimize", sampler=_sampler(cfg), storage=storage,
                                study_name=cfg.study_name, load_if_exists=True)
    remaining = cfg.n_trials - len([t for t in study.trials if t.state.is_finished()])
    if remaining > 0:
        study.optimize(objective, n_trials=remaining)
    trials = [{"number": t.number, "value": t.value, **t.params, **t.user_attrs} for t in study.trials
              if t.value is not None]
    truth = {k: float(TRUTH[k]) for k in cfg.space if k in TRUTH}
    return OptimizeResult(dict(study.best_params), float(study.best_value), truth, study, trials,
                          best_decile(trials, list(cfg.space)))


def plot_optimization(res: OptimizeResult, out: str | Path) -> list[Path]:
    """Optimisation history and parameter importances (PNG + SVG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import optuna

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    values = [t["value"] for t in res.trials]
    fig, axes = plt.subplots(1, 1 + len(res.best_params), figsize=(4.2 * (1 + len(res.best_params)), 3.4))
    axes = np.atleast_1d(axes)
    axes[0].plot(values, ".", alpha=0.6, label="trial")
    axes[0].plot(np.minimum.accumulate(values), "-", color="tab:red", label="best so far")
    axes[0].set_xlabel("trial")
    axes[0].set_ylabel("objective")
    axes[0].legend(fontsize=8)
    for ax, name in zip(axes[1:], res.best_params, strict=True):
        ax.scatter([t[name] for t in res.trials], values, s=12, c=range(len(values)), cmap="viridis")
        if name in res.truth:
            ax.axvline(res.truth[name], color="tab:red", ls="--", lw=1, label="truth")
        ax.axvline(res.recovered.get(name, res.best_params[name]), color="k", ls=":", lw=1,
                   label="recovered (best decile)")
        ax.set_xlabel(name)
        ax.legend(fontsize=8)
    fig.suptitle("proxy optimisation against the reality model (simulated target)", fontsize=10)
    fig.tight_layout()
    paths = [out / "optimization_history.png"]
    fig.savefig(paths[0], dpi=110)
    fig.savefig(paths[0].with_suffix(".svg"))
    plt.close(fig)
    if len(res.best_params) > 1 and len(res.trials) > 2:
        imp = optuna.importance.get_param_importances(res.study)
        fig, ax = plt.subplots(figsize=(4.5, 0.6 + 0.5 * len(imp)))
        ax.barh(list(imp), list(imp.values()))
        ax.set_xlabel("importance (fANOVA)")
        fig.tight_layout()
        paths.append(out / "param_importance.png")
        fig.savefig(paths[-1], dpi=110)
        fig.savefig(paths[-1].with_suffix(".svg"))
        plt.close(fig)
    return paths
