"""Proxy optimisation: θ* = argmin PRPV (thesis eq. 3.6.1; or PPV, or a mix) over simulator parameters.

Any kind of target works. Each Optuna trial proposes θ, the runner replays the target's episodes in that
proxy (same agents, starts and seeds; cached, so repeated θ cost nothing, and Ray works), and the objective
compares the proxy's results with the target's (:mod:`proxybench.targets`: the reality model, a recording,
or a robot node, whose episodes are run once and re-used by every trial). The search space comes from the experiment
(default: around the nominal calibration, :mod:`proxybench.experiments.proxies`), never from a target's
truth; a known truth is only printed beside what was recovered.
The objective is PRPV by default, as the thesis defines θ*; ``ppv`` (the mean per-agent PPV) and ``mix``
(PRPV/K(K−1) + PPV/m: both in [0, 1]-ish units, and PPV's slope gives the sampler something to follow where
PRPV is flat) can be chosen. The teaching objective, argmax PLV (eq. 3.6.2), trains an agent instead:
:mod:`proxybench.experiments.optimize.plv_search`.
Studies live in memory, in SQLite (default when a path is given) or in any SQLAlchemy database such as
PostgreSQL, so many workers can share one study.
"""

from __future__ import annotations

import textwrap
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.domain.params import DomainParams
from proxybench.experiments.config import OBJECTIVES, Experiment, ExperimentConfig, resolve_run
from proxybench.experiments.predictivity.run import proxy_jobs
from proxybench.experiments.proxies import param_label, proxy_params
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import DomainSpec
from proxybench.runner.sweep import run_jobs
from proxybench.targets.base import Target, TargetInfo, by_agent
from proxybench.tasks.metrics import METRICS
from proxybench.usefulness.metrics import Estimate, PairedResults, dominance, ppv_value, prpv_value
from proxybench.usefulness.noise import compare_paired, noise_floor, paired_prpv_samples

__all__ = [
    "OBJECTIVES",
    "OptimizeResult",
    "TiedSet",
    "Trial",
    "optimize_proxy",
    "plot_optimization",
    "tied_set",
    "write_optimization",
]


@dataclass(frozen=True)
class TiedSet:
    """The trials the data cannot tell from the best one, and what θ they span.

    A trial is tied with the best when the paired interval of ΔPRPV (the same target episodes resampled in
    both) contains 0. ``spread``: per parameter, (median, min, max) over the tied set: a summary that does
    not depend on the order trials ran in (the mean of "the first few at the best value" did).
    """

    trials: tuple[int, ...]  # trial numbers, the best first
    spread: dict[str, tuple[float, float, float]]
    separated: bool  # the best trial is separated from every other one

    def warning(self) -> str | None:
        """What to tell the user when the best θ is not one θ but a set."""
        if self.separated:
            return None
        ranges = "; ".join(f"{k} {lo:.4g} … {hi:.4g}" for k, (_, lo, hi) in self.spread.items())
        return (f"the best trial is not separated from {len(self.trials) - 1} other(s) (paired 95 % intervals of "
                f"ΔPRPV contain 0): the data support θ anywhere in {ranges}; more target episodes narrow it "
                f"(`proxybench plan`)")


@dataclass(frozen=True)
class Trial:
    """One finished trial: its number, its objective's value, the θ it tried and the figures its objective
    reported beside the value (``prpv``, ``ppv``)."""

    number: int
    value: float
    theta: dict[str, float]
    prpv: float | None = None
    ppv: float | None = None

    @classmethod
    def of(cls, trial: Any) -> Trial:
        """From an Optuna ``FrozenTrial`` (its params are θ, its user attributes the figures)."""
        attrs = trial.user_attrs
        return cls(trial.number, float(trial.value), dict(trial.params), attrs.get("prpv"), attrs.get("ppv"))

    def to_dict(self) -> dict[str, Any]:
        """A row of ``trials.json``: number, value, θ by name, the figures."""
        return {"number": self.number, "value": self.value, **self.theta, "prpv": self.prpv, "ppv": self.ppv}


@dataclass
class OptimizeResult:
    """θ* and its objective value (the residual gap), the known truth beside it (if any), and the study.

    Each trial's objective is itself an estimate from a few episodes per agent, so the single best trial
    is partly luck. ``tied``: the trials the data cannot tell from the best (objective prpv), with their
    spread per parameter; ``recovered`` is the median θ of that tied set (for the other objectives, the
    mean θ of the best decile, at least 3 trials). ``best_params`` is the single best trial.
    ``noise_floor``: PRPV of the target against a replicate of itself (the PRPV no proxy can beat
    reliably with this many episodes).
    """

    best_params: dict[str, float]
    best_value: float
    truth: dict[str, float]
    study: Any
    trials: list[Trial]
    recovered: dict[str, float] = field(default_factory=dict)
    target: TargetInfo | None = None
    experiment: Experiment | None = None
    noise_floor: Estimate | None = None
    target_episodes_run: int = 0
    tied: TiedSet | None = None

    def errors(self) -> dict[str, float]:
        return {k: v - self.truth[k] for k, v in self.recovered.items() if k in self.truth}


def best_decile(trials: list[Trial], names: list[str]) -> dict[str, float]:
    """Mean θ of the best tenth of the trials (at least 3, at most all)."""
    ranked = sorted(trials, key=lambda t: t.value)
    top = ranked[: max(3, len(ranked) // 10)]
    return {n: float(np.mean([t.theta[n] for t in top])) for n in names} if top else {}


def tied_set(trials: list[Trial], proxies: dict[int, Mapping[str, np.ndarray]],
             target: Mapping[str, np.ndarray], higher: tuple[bool, ...], names: list[str], *, n_boot: int,
             seed: int) -> TiedSet:
    """The trials whose PRPV is not separated from the best trial's (paired intervals of ΔPRPV)."""
    done = sorted((t for t in trials if t.prpv is not None and t.number in proxies), key=lambda t: (t.prpv, t.number))
    if not done:
        return TiedSet((), {}, True)
    samples = paired_prpv_samples(target, [proxies[t.number] for t in done], higher, n_boot=n_boot, seed=seed)
    labels = [str(t.number) for t in done]
    points = [float(t.prpv or 0.0) for t in done]
    tied = [0] + [j for j in range(1, len(done)) if not compare_paired(labels, points, samples, 0, j).separated]
    members = [done[j] for j in tied]
    spread = {n: (float(np.median([m.theta[n] for m in members])), float(min(m.theta[n] for m in members)),
                  float(max(m.theta[n] for m in members))) for n in names}
    return TiedSet(tuple(m.number for m in members), spread, len(members) == 1)


def _objective_value(kind: str, proxy: Mapping[str, np.ndarray], target: Mapping[str, np.ndarray],
                     higher: tuple[bool, ...]) -> tuple[float, dict[str, float]]:
    pr = PairedResults(dict(proxy), dict(target), higher)
    k = len(pr.agents)
    prpv = prpv_value(dominance(pr.proxy, higher), dominance(pr.target, higher))
    ppv = ppv_value(pr.proxy, pr.target)  # mean over agents of the thesis' per-agent PPV
    norm_prpv, norm_ppv = prpv / max(k * (k - 1), 1), ppv / len(higher)
    value = {"prpv": prpv, "ppv": ppv, "mix": norm_prpv + norm_ppv}[kind]
    return value, {"prpv": prpv, "ppv": ppv}


def _is_count(name: str) -> bool:
    """An integer domain parameter (e.g. ``extra_duckies``): Optuna proposes whole numbers for it."""
    field = DomainParams.model_fields.get(name)
    return field is not None and field.annotation is int


def _sampler(exp: Experiment):
    import optuna

    if exp.search.sampler == "gp":
        return optuna.samplers.GPSampler(seed=exp.seed)
    if exp.search.sampler == "random":
        return optuna.samplers.RandomSampler(seed=exp.seed)
    return optuna.samplers.TPESampler(seed=exp.seed, n_startup_trials=min(10, exp.trials))


def optimize_proxy(
    cfg: ExperimentConfig | Experiment, run_dir: str | Path, backend: Backend | None = None,
    progress: Callable[[int, int, float], None] | None = None, *, quick: bool = False, target: Target | None = None,
    target_progress: Callable[[str, int, int], None] | None = None,
) -> OptimizeResult:
    """Search ``search.space`` for the proxy θ whose verdicts best match the target's.

    ``cfg`` as for :func:`~proxybench.experiments.predictivity.run.run_predictivity`. The target's episodes are
    run (or read) once; every trial replays them in its proxy.
    """
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    backend = backend or InlineBackend()
    run_dir = Path(run_dir)
    if cfg.search.objective == "plv":
        raise ValueError("search.objective: plv trains a learning agent; run it with proxybench.experiments."
                         "optimize_plv.run_plv_search (or `proxybench optimize --objective plv`)")
    exp, target = resolve_run(cfg, "optimize", run_dir, quick=quick, target=target)
    higher = tuple(METRICS[m].higher_is_better for m in exp.metrics)
    tgt = target.run(exp.agents, map_name=exp.map, seconds=exp.seconds, episodes=exp.episodes, seed=exp.seed,
                     metrics=exp.metrics, image_size=exp.image_size, run_dir=run_dir, backend=backend,
                     progress=target_progress)
    space = exp.search.space

    def proxy_of(theta: dict[str, Any]) -> dict[str, np.ndarray]:
        """The proxy's per-agent results at θ (run, or read from the run directory's cache)."""
        params = proxy_params(exp.image_size, exp.proxy, **theta)
        dom = DomainSpec("proxy " + " ".join(f"{k}={v:.4g}" for k, v in theta.items()), params)
        jobs = proxy_jobs(exp, tgt, dom)
        return by_agent(jobs, run_jobs(jobs, run_dir, backend).results, exp.metrics)

    def objective(trial) -> float:
        theta = {name: trial.suggest_int(name, int(lo), int(hi)) if _is_count(name)
                 else trial.suggest_float(name, lo, hi) for name, (lo, hi) in space.items()}  # counts are ints
        proxy = proxy_of(theta)
        value, parts = _objective_value(exp.search.objective, proxy, tgt.results, higher)
        for k, v in parts.items():
            trial.set_user_attr(k, v)
        if progress:
            progress(trial.number + 1, exp.trials, value)
        return value

    storage = exp.search.storage
    if storage and "://" not in storage:
        storage = f"sqlite:///{Path(storage).resolve()}"
    study = optuna.create_study(direction="minimize", sampler=_sampler(exp), storage=storage,
                                study_name=exp.search.study_name, load_if_exists=True)
    remaining = exp.trials - len([t for t in study.trials if t.state.is_finished()])
    if remaining > 0:
        study.optimize(objective, n_trials=remaining)
    trials = [Trial.of(t) for t in study.trials if t.value is not None]
    known = {**tgt.truth, **exp.truth}
    truth = {k: float(known[k]) for k in space if k in known}
    floor = noise_floor(tgt.results, higher, n_boot=exp.n_boot, seed=exp.seed)
    tied = None
    recovered = best_decile(trials, list(space))
    if exp.search.objective == "prpv":  # the trials' proxies again: each from the cache of its episodes
        proxies = {t.number: proxy_of({n: t.theta[n] for n in space}) for t in trials}
        tied = tied_set(trials, proxies, tgt.results, higher, list(space), n_boot=exp.n_boot, seed=exp.seed)
        recovered = {n: med for n, (med, _, _) in tied.spread.items()}
    return OptimizeResult(dict(study.best_params), float(study.best_value), truth, study, trials,
                          recovered, tgt.info, exp, floor, tgt.ran, tied)


def plot_optimization(res: OptimizeResult, out: str | Path) -> list[Path]:
    """Optimisation history and parameter importances (PNG + SVG)."""
    import optuna

    from proxybench.plots import pyplot, save_figure

    plt = pyplot()

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    values = [t.value for t in res.trials]
    objective = res.experiment.search.objective if res.experiment is not None else "objective"
    ylabel = {"prpv": "PRPV [0, K(K−1)] (↓)", "ppv": "PPV (↓)",
              "mix": "PRPV/K(K−1) + PPV/m (↓)"}.get(objective, "objective (↓)")
    fig, axes = plt.subplots(1, 1 + len(res.best_params), figsize=(4.4 * (1 + len(res.best_params)), 3.6),
                             layout="constrained")
    axes = np.atleast_1d(axes)
    axes[0].plot(values, ".", alpha=0.6, label="trial")
    axes[0].plot(np.minimum.accumulate(values), "-", color="tab:red", label="best so far")
    if objective == "prpv" and res.noise_floor is not None:
        axes[0].axhspan(res.noise_floor.low, res.noise_floor.high, color="0.6", alpha=0.3, lw=0,
                        label="target noise floor (95%)")
    axes[0].set_xlabel("trial number")
    axes[0].set_ylabel(ylabel)
    axes[0].legend(fontsize=8)
    points = None
    for ax, name in zip(axes[1:], res.best_params, strict=True):
        points = ax.scatter([t.theta[name] for t in res.trials], values, s=12, c=range(len(values)), cmap="viridis",
                            label="trial (colour: trial number)")
        if name in res.truth:
            ax.axvline(res.truth[name], color="tab:red", ls="--", lw=1, label="known truth (not used by the search)")
        if res.tied is not None and name in res.tied.spread:
            _, lo, hi = res.tied.spread[name]
            ax.axvspan(lo, hi, color="0.6", alpha=0.25, lw=0, label="tied with the best (paired 95 %)")
        ax.axvline(res.recovered.get(name, res.best_params[name]), color="k", ls=":", lw=1,
                   label="recovered (tied-set median)" if res.tied is not None else "recovered (best decile)")
        ax.set_xlabel(param_label(name))
        ax.set_ylabel(ylabel)
        ax.legend(fontsize=7)
    if points is not None:
        fig.colorbar(points, ax=list(axes[1:]), label="trial number", fraction=0.03)
    what = res.target.label if res.target is not None else "the target"
    fig.suptitle(textwrap.shorten(f"proxy optimisation against {what}", 150, placeholder=" …"), fontsize=10)
    paths = [out / "optimization_history.png"]
    save_figure(fig, paths[0])
    if len(res.best_params) > 1 and len(res.trials) > 2:
        imp = optuna.importance.get_param_importances(res.study)
        fig, ax = plt.subplots(figsize=(4.5, 0.6 + 0.5 * len(imp)))
        ax.barh(list(imp), list(imp.values()))
        ax.set_xlabel("importance (fANOVA)")
        fig.tight_layout()
        paths.append(out / "param_importance.png")
        save_figure(fig, paths[-1])
    return paths


def write_optimization(res: OptimizeResult, out: str | Path, wall_s: float) -> list[Path]:
    """The plots, ``trials.json`` and ``summary.json`` (θ*, the recovered θ beside the truth, the noise floor)."""
    import json

    out = Path(out)
    paths = plot_optimization(res, out)
    nf = res.noise_floor
    summary = {"target": res.target.statement if res.target else None, "recovered": res.recovered,
               "best_params": res.best_params, "best_value": res.best_value, "truth": res.truth,
               "noise_floor_prpv": [nf.value, nf.low, nf.high] if nf else None, "wall_s": round(wall_s, 1),
               "tied": None if res.tied is None else {"trials": list(res.tied.trials), "separated": res.tied.separated,
                                                      "spread": {k: dict(zip(("median", "min", "max"), v, strict=True))
                                                                 for k, v in res.tied.spread.items()}},
               "experiment": res.experiment.to_dict() if res.experiment else None}
    (out / "trials.json").write_text(json.dumps([t.to_dict() for t in res.trials], indent=1))
    (out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))
    return [*paths, out / "trials.json", out / "summary.json"]
