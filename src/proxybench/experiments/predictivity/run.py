"""The thesis' predictivity experiment (figures 3.3 and 3.4) against any target, as an importable function.

K agents are evaluated on the *target* (the reality model, a recorded directory or a robot node:
:mod:`proxybench.targets`) and on proxy instances θ of the simulator swept around its nominal calibration
(:mod:`proxybench.experiments.proxies`). Each proxy replays every agent's target episodes from the same
start poses and seeds, so proxy and target episodes are paired. For every θ: PRPV with its order range,
PPV (per agent, mean, sum), Pearson's r (SRCC), Spearman's ρ, Kendall's τ and MMRV per metric with paired
BCa intervals (:mod:`proxybench.usefulness.intervals`), and POD where the target's θ is known; beside them the target's
own noise floor and paired comparisons between θ values (:mod:`proxybench.usefulness.noise`), so that a
minimum is only claimed where the data separate it from its neighbours.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.domain.kinds import DomainKind
from proxybench.domain.maps import load_map
from proxybench.experiments.baselines import NOMINAL, baseline_tables, baselines, diagnose
from proxybench.experiments.config import Experiment, ExperimentConfig, resolve_run
from proxybench.experiments.predictivity.pod import pod
from proxybench.experiments.proxies import proxy_params
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import DomainSpec, Job, JobResult
from proxybench.runner.sweep import run_jobs
from proxybench.targets.base import Target, TargetRun, by_agent
from proxybench.tasks.metrics import METRICS
from proxybench.usefulness.agent_sets import means_of, order_structure, sensitivity
from proxybench.usefulness.diagnosis import PairDisagreement
from proxybench.usefulness.intervals import Usefulness, usefulness
from proxybench.usefulness.metrics import Estimate, PairedResults, agent_means
from proxybench.usefulness.noise import compare_paired, lowest_claim, noise_floor, paired_prpv_samples, ppv_noise_floor

__all__ = ["PredictivityResult", "SweepClaim", "measure_predictivity", "proxy_domains", "proxy_jobs",
           "run_predictivity"]

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class SweepClaim:
    """What the data say about the minimum of PRPV along one parameter."""

    parameter: str
    best: float
    separated: bool  # lower than each neighbour, with paired intervals excluding 0
    plausible: tuple[float, ...]  # every value not separated from the best
    neighbours: tuple[tuple[float, Estimate], ...]  # (neighbour value, ΔPRPV best − neighbour)


@dataclass(frozen=True)
class BestProxy:
    """The swept proxy of lowest PRPV: where it is (parameter, value, domain) and its figures with intervals."""

    parameter: str
    value: float
    domain: str
    prpv: Estimate
    ppv: Estimate
    pearson: float
    spearman: float
    kendall: float

    @classmethod
    def of(cls, row: dict[str, Any]) -> BestProxy:
        """From a row of the result's table (``usefulness.csv``: a figure and its ``_low`` / ``_high``)."""
        def est(name: str) -> Estimate:
            return Estimate(row[name], row.get(f"{name}_low", float("nan")), row.get(f"{name}_high", float("nan")))

        return cls(row["parameter"], row["value"], row.get("domain", ""), est("prpv"), est("ppv"),
                   row.get("pearson", float("nan")), row.get("spearman", float("nan")),
                   row.get("kendall", float("nan")))


@dataclass
class PredictivityResult:
    """One row per (swept parameter, value) with the usefulness figures; the target, its noise floor, claims."""

    rows: list[dict[str, Any]]
    experiment: Experiment
    target: TargetRun
    target_scores: dict[str, dict[str, float]]
    noise: Estimate
    claims: dict[str, SweepClaim] = field(default_factory=dict)
    proxy_episodes: int = 0  # proxy episodes simulated now (not cached)
    details: dict[str, Usefulness] = field(default_factory=dict)  # per proxy domain: per-agent PPV, notes, open pairs
    ppv_noise: Estimate | None = None  # PPV of the target against a replicate of itself
    agent_sensitivity: dict[str, Any] = field(default_factory=dict)  # parameter → agent_sets.AgentSensitivity
    order: dict[str, float] = field(default_factory=dict)  # agent_sets.order_structure of the target
    baselines: dict[str, Usefulness] = field(default_factory=dict)  # experiments.baselines: no tuning, no simulator
    diagnosis: dict[str, list[PairDisagreement]] = field(default_factory=dict)  # predictor → pairs it orders wrong
    localisation: Any = None  # autolab.effect.LocalisationEffect: a localised target scored against its truth

    def notes(self) -> list[str]:
        """Every distinct note of the usefulness figures (constant metrics, missing values, PPV scales)."""
        return list(dict.fromkeys(n for u in self.details.values() for n in u.notes))

    def frame(self):
        import pandas as pd

        return pd.DataFrame(self.rows)

    @property
    def config(self) -> Experiment:
        return self.experiment

    def best_row(self) -> BestProxy:
        """The swept proxy of lowest PRPV (the first of equals), its figures typed."""
        return BestProxy.of(min(self.rows, key=lambda r: r["prpv"]))


def proxy_domains(exp: Experiment) -> list[tuple[str, float, DomainSpec]]:
    """(parameter, value, proxy domain) for every sweep point; equal θ share one cached result."""
    out = []
    for name, values in exp.sweep.items():
        for v in values:
            params = proxy_params(exp.image_size, exp.proxy, **{name: v})
            out.append((name, float(v), DomainSpec(f"{name}={v:g}", params)))
    return out


def proxy_jobs(exp: Experiment, tgt: TargetRun, dom: DomainSpec) -> list[Job]:
    """The target's episodes replayed in one proxy: same agents, episode ids, seeds and start poses."""
    specs = {a.label: a for a in exp.agents}
    return [Job(specs[e.agent], dom, tgt.map, e.episode, e.seed, tgt.seconds, pose=e.pose, metrics=exp.metrics)
            for e in tgt.episodes]


def run_predictivity(
    cfg: ExperimentConfig | Experiment, run_dir: str | Path, backend: Backend | None = None,
    progress: Progress | None = None, *, quick: bool = False, target: Target | None = None,
) -> PredictivityResult:
    """Run (or resume) the whole experiment; episodes are cached in ``run_dir``.

    ``cfg``: an experiment file's content (resolved against the target and the command's defaults, the quick
    ones with ``quick``) or an already resolved :class:`Experiment` (then ``target`` too, or its text is opened).
    """
    backend = backend or InlineBackend()
    run_dir = Path(run_dir)
    exp, target = resolve_run(cfg, "predictivity", run_dir, quick=quick, target=target)
    tgt = target.run(exp.agents, map_name=exp.map, seconds=exp.seconds, episodes=exp.episodes, seed=exp.seed,
                     metrics=exp.metrics, image_size=exp.image_size, run_dir=run_dir, backend=backend,
                     progress=progress)
    domains = proxy_domains(exp)
    nominal = DomainSpec(NOMINAL, proxy_params(exp.image_size, exp.proxy))  # cached if swept
    jobs = [j for _, _, d in domains for j in proxy_jobs(exp, tgt, d)] + proxy_jobs(exp, tgt, nominal)
    sweep = run_jobs(jobs, run_dir, backend,
                     progress=(lambda done, total, _r: progress("proxy episodes", done, total)) if progress else None)
    by_domain: dict[str, tuple[list[Job], list[JobResult]]] = {}
    for job, r in zip(jobs, sweep.results, strict=True):
        js, rs = by_domain.setdefault(job.domain.name, ([], []))
        js.append(job)
        rs.append(r)
    proxies = {name: by_agent(js, rs, exp.metrics) for name, (js, rs) in by_domain.items()}
    commands = _pod_commands(exp, tgt) if _has_pod(exp, target, tgt) else None
    from proxybench.autolab.effect import effect_for_target  # a target localised from simulated watchtowers

    return measure_predictivity(exp, tgt, domains, proxies, progress, commands=commands, proxy_episodes=sweep.ran,
                                localisation=effect_for_target(target, exp.metrics, exp.n_boot, exp.seed))


def measure_predictivity(exp: Experiment, tgt: TargetRun, domains: list[tuple[str, float, DomainSpec]],
                         proxies: dict[str, dict[str, np.ndarray]], progress: Progress | None = None, *,
                         commands: np.ndarray | None = None, proxy_episodes: int = 0,
                         localisation: Any = None) -> PredictivityResult:
    """The study's measures from its tables: the target's and each proxy's per-agent scores (``proxies``: one per
    swept domain and the nominal θ), POD from the target's ``commands`` where given. Runs no episode."""
    higher = tuple(METRICS[m].higher_is_better for m in exp.metrics)
    truth = {**tgt.truth, **exp.truth}
    rows, details = [], {}
    for k, (param, value, dom) in enumerate(domains):
        est = usefulness(PairedResults(proxies[dom.name], tgt.results, higher, exp.metrics), n_boot=exp.n_boot,
                         seed=exp.seed)
        details[dom.name] = est
        row: dict[str, Any] = {"parameter": param, "value": value, "domain": dom.name,
                               "truth": float(truth.get(param, np.nan))}
        for name, e in est.items():
            row[name], row[f"{name}_low"], row[f"{name}_high"] = e.value, e.low, e.high
        row["notes"] = "; ".join(est.notes)
        row["pod"] = (pod(dom.params, tgt.params, tgt.map,
                          commands, seed=exp.seed) if commands is not None else float("nan"))
        rows.append(row)
        if progress:
            progress("usefulness", k + 1, len(domains))
    floor = noise_floor(tgt.results, higher, n_boot=exp.n_boot, seed=exp.seed)
    ppv_floor = ppv_noise_floor(tgt.results, n_boot=exp.n_boot, seed=exp.seed)
    claims = _claims(exp, tgt, domains, proxies, rows, higher)
    means = agent_means(tgt.results, list(tgt.results))
    target_scores = {a: dict(zip(exp.metrics, means[i].tolist(), strict=True)) for i, a in enumerate(tgt.results)}
    caps = [tgt.seconds if m in ("survival_time", "lane_score") else None for m in exp.metrics]
    base = baselines(tgt, proxies[NOMINAL], higher, exp.metrics, n_boot=exp.n_boot, seed=exp.seed)
    best = min(rows, key=lambda r: r["prpv"])["domain"]
    size = load_map(tgt.map).size_m
    diagnosis = diagnose({f"best proxy ({best})": proxies[best], **baseline_tables(tgt, proxies[NOMINAL], higher)},
                         tgt, higher, exp.metrics, size)
    return PredictivityResult(rows, exp, tgt, target_scores, floor, claims, proxy_episodes, details, ppv_floor,
                              _agent_sensitivity(exp, domains, proxies, tgt, higher),
                              order_structure(tgt.results, higher, caps), base, diagnosis, localisation)


def _agent_sensitivity(exp: Experiment, domains, proxies, tgt: TargetRun, higher) -> dict[str, Any]:
    """Per swept parameter (in value order): PRPV's argmin without each agent, and over bootstrap agent sets."""
    agents = list(tgt.results)
    sign = np.where(np.asarray(higher), 1.0, -1.0)
    tm = means_of(tgt.results, agents) * sign
    out = {}
    for name in exp.sweep:
        order = sorted((k for k, (p, _, _) in enumerate(domains) if p == name), key=lambda k: domains[k][1])
        pm = np.stack([means_of(proxies[domains[k][2].name], agents) * sign for k in order])
        out[name] = sensitivity(agents, pm, tm, (True,) * tm.shape[1], n_boot=exp.n_boot, seed=exp.seed)
    return out


def _claims(exp: Experiment, tgt: TargetRun, domains, proxies, rows, higher) -> dict[str, SweepClaim]:
    """Per parameter: the paired comparison of every value with the best (adds delta_best columns to rows)."""
    out = {}
    for name in exp.sweep:
        idx = [k for k, (p, _, _) in enumerate(domains) if p == name]
        order = sorted(idx, key=lambda k: domains[k][1])
        values = [domains[k][1] for k in order]
        labels = [domains[k][2].name for k in order]
        points = [rows[k]["prpv"] for k in order]
        samples = paired_prpv_samples(tgt.results, [proxies[lb] for lb in labels], higher, n_boot=exp.n_boot,
                                      seed=exp.seed)
        best, comps, plausible = lowest_claim(labels, points, samples)
        for j, k in enumerate(order):
            c = compare_paired(labels, points, samples, j, best)
            rows[k].update({"delta_best": c.delta.value, "delta_best_low": c.delta.low,
                            "delta_best_high": c.delta.high, "plausible": j in plausible})
        neigh = tuple((values[labels.index(c.b)], c.delta) for c in comps)
        out[name] = SweepClaim(name, values[best], bool(comps) and all(c.a_lower for c in comps),
                               tuple(values[j] for j in plausible), neigh)
    return out


def _has_pod(exp: Experiment, target: Target, tgt: TargetRun) -> bool:
    """POD needs the target's camera: known only for the live reality model."""
    return exp.pod_seconds > 0 and target.kind == DomainKind.REALITY_MODEL and tgt.params is not None


def _pod_commands(exp: Experiment, tgt: TargetRun) -> np.ndarray:
    """The commands the privileged PID agent issues on the target: a realistic open-loop sequence for POD."""
    from proxybench.agents import make_agent
    from proxybench.runner.replay import agent_commands

    return agent_commands(tgt.map, tgt.params, make_agent("pid"), exp.seed,
                          exp.pod_seconds)
