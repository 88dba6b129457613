"""The two uses of a simulator, side by side on one target: argmin PRPV (to predict) against argmax PLV (to teach).

Thesis §3.6 names two objectives for choosing a proxy θ: θ* = argmin PRPV(θ) when the simulator is to *rank
agents* as the target would (eq. 3.6.1), and p(θ)* = argmax PLV(θ) when it is to *pre-train* a learning agent
(eq. 3.6.2). Do they pick the same θ? For every candidate θ (the experiment's sweep points, each the nominal
calibration with one parameter changed):

- PRPV of the agents' replays against the target, with its order range, and the paired difference to the
  lowest candidate (the same resampled episodes): the candidates the data cannot tell from the lowest are
  PRPV's tied set (:func:`~proxybench.usefulness.noise.lowest_claim`);
- PLV of a behaviour-cloning agent pre-trained on the candidate and fine-tuned on target samples (fitted
  learning curves, bootstrap interval over seeds: :class:`~proxybench.experiments.plv.objective.PLVObjective`);
  the candidates whose interval reaches the best one's are PLV's tied set.

The two picks differ *for sure* only when the tied sets are disjoint. The target is the same for both: the
reality model, or a robot node (``robot:COMMAND``; PLV then collects its target samples on the node).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.experiments.config import ConfigError, ExperimentConfig, resolve
from proxybench.experiments.predictivity.run import proxy_jobs
from proxybench.experiments.proxies import NOMINAL, proxy_params
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import DomainSpec
from proxybench.runner.sweep import run_jobs
from proxybench.targets.base import by_agent
from proxybench.tasks.metrics import METRICS
from proxybench.usefulness.intervals import usefulness
from proxybench.usefulness.metrics import PairedResults
from proxybench.usefulness.noise import compare_paired, lowest_claim, paired_prpv_samples

__all__ = ["DEFAULT_CANDIDATES", "Candidate", "ChoiceResult", "EpisodeScores", "candidates_of", "instance_theta",
           "plv_picks", "prpv_of_candidates", "recompute_choice", "run_candidates",
           "run_plv_prpv"]

#: when the experiment sweeps nothing: camera pitch below, at and above the nominal calibration
DEFAULT_CANDIDATES = {"camera_pitch": (12.0, 19.15, 26.0)}
Progress = Callable[[str, int, int], None]


@dataclass
class Candidate:
    """One θ and what each objective says of it."""

    label: str
    theta: dict[str, float]
    prpv: float = float("nan")
    prpv_low: float = float("nan")  # order range
    prpv_high: float = float("nan")
    delta: tuple[float, float, float] = (0.0, 0.0, 0.0)  # PRPV − lowest PRPV [paired 95 % interval]
    plv: float | None = None
    plv_low: float | None = None
    plv_high: float | None = None
    plv_label: str = ""
    reached: float = 0.0
    zero_shot: float = float("nan")


@dataclass
class ChoiceResult:
    """Every candidate, each objective's pick and tied set, and whether the two uses of the simulator differ."""

    candidates: list[Candidate]
    prpv_pick: str
    prpv_tied: list[str]
    plv_pick: str | None
    plv_tied: list[str]
    target: str
    agents: list[str]
    episodes: int
    plv_seeds: int
    reference: float
    target_samples: float | None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def same(self) -> bool:
        return self.plv_pick == self.prpv_pick

    @property
    def resolved(self) -> bool:
        """The picks differ and no candidate is in both tied sets: the two uses choose different θ for sure."""
        return not self.same and not set(self.prpv_tied) & set(self.plv_tied)

    def verdict(self) -> str:
        if self.plv_pick is None:
            return "PLV picks nothing: no candidate reaches the reference score P"
        if self.same:
            others = sorted((set(self.prpv_tied) | set(self.plv_tied)) - {self.prpv_pick})
            return f"both pick {self.prpv_pick}" + (f" (not separated from {', '.join(others)})" if others else "")
        if self.resolved:
            return (f"they differ: argmin PRPV {self.prpv_pick}, argmax PLV {self.plv_pick}, and the tied sets do "
                    "not overlap")
        both = ", ".join(sorted(set(self.prpv_tied) & set(self.plv_tied)))
        return (f"argmin PRPV {self.prpv_pick}, argmax PLV {self.plv_pick}, but the data cannot tell them apart: "
                f"{both} {'is' if ', ' not in both else 'are'} in both tied sets")

    def to_dict(self) -> dict[str, Any]:
        return {**{k: v for k, v in asdict(self).items() if k != "candidates"},
                "candidates": [asdict(c) for c in self.candidates], "same": self.same, "resolved": self.resolved,
                "verdict": self.verdict()}


def candidates_of(sweep: dict[str, tuple[float, ...]], fixed: dict[str, Any]) -> list[tuple[str, dict[str, float]]]:
    """(label, θ changes) per sweep point, one parameter changed at a time; equal θ (the nominal value of several
    parameters) once."""
    out: dict[str, tuple[str, dict[str, float]]] = {}
    for name, values in sweep.items():
        for v in values:
            theta = {name: float(v)}
            key = "nominal" if np.isclose(float(v), float(NOMINAL.get(name, np.nan))) else f"{name}={v:g}"
            out.setdefault(key, (key, theta))
    return list(out.values())


def _from_run(cfg: ExperimentConfig) -> Path | None:
    """``plv: {from_run: DIR}``: PLV read from a finished run instead of trained; then no other PLV setting, which
    would be silently ignored."""
    if "from_run" not in cfg.plv:
        return None
    others = sorted(k for k in cfg.plv if k != "from_run")
    if others:
        raise ConfigError(f"plv.{others[0]}: with plv.from_run the PLV settings are the run's; drop {others[0]}")
    return Path(str(cfg.plv["from_run"]))


def run_plv_prpv(cfg: ExperimentConfig, out: str | Path, *, quick: bool = False, backend: Backend | None = None,
                 progress: Progress | None = None) -> ChoiceResult:
    """PRPV and PLV of every candidate θ on the experiment's target; both picks with their tied sets."""
    from proxybench.experiments.optimize.plv_search import plv_search_settings
    from proxybench.experiments.plv.objective import PLVObjective, instance_domain

    if cfg.target != "reality" and not cfg.target.startswith("robot:"):
        raise ConfigError(f"target: PLV collects target samples and scores networks on the target, so it needs a live "
                          f"one (reality, or robot:COMMAND), not {cfg.target!r}")
    if cfg.target_params:
        raise ConfigError("target_params: PLV's reality model is the calibrated one; drop target_params")
    out, backend = Path(out), backend or InlineBackend()
    from_run = _from_run(cfg)
    if from_run is not None and cfg.proxy:
        raise ConfigError(f"proxy: a PLV run's proxies are the nominal calibration with one θ changed; with "
                          f"plv.from_run drop proxy ({', '.join(sorted(cfg.proxy))})")
    exp, target = resolve(cfg, "predictivity", quick=quick, work_dir=out / "agents")
    if "sweep" in cfg.model_fields_set:
        cands = candidates_of(dict(cfg.sweep), exp.proxy)
    else:
        cands = run_candidates(from_run) if from_run is not None else candidates_of(DEFAULT_CANDIDATES, exp.proxy)
    # predicting: the agents on the target, replayed in every candidate
    tgt = target.run(exp.agents, map_name=exp.map, seconds=exp.seconds, episodes=exp.episodes, seed=exp.seed,
                     metrics=exp.metrics, image_size=exp.image_size, run_dir=out / "runs", backend=backend,
                     progress=progress)
    proxies = {}
    for label, theta in cands:
        dom = DomainSpec(label, proxy_params(exp.image_size, exp.proxy, **theta))
        jobs = proxy_jobs(exp, tgt, dom)
        proxies[label] = by_agent(jobs, run_jobs(jobs, out / "runs", backend).results, exp.metrics)
    rows = [Candidate(label, theta) for label, theta in cands]
    scores = EpisodeScores(tgt.results, proxies, tuple(exp.metrics))
    best, plausible = prpv_of_candidates(rows, scores, exp.n_boot, exp.seed)
    labels = [c.label for c in rows]
    episodes = {"episode_scores": scores.to_dict(), "n_boot": exp.n_boot, "seed": exp.seed}
    if from_run is not None:
        seeds, reference, t_cost, extra = _plv_from_run(rows, from_run, cfg.target)
        return _choice(rows, labels, best, plausible, tgt, exp, seeds, reference, t_cost, {**extra, **episodes})
    # teaching: a network pre-trained on each candidate, fine-tuned on target samples
    plv_cfg, _, _ = plv_search_settings(cfg.model_copy(update={"target": "reality"}), quick=quick)
    plv_cfg = type(plv_cfg).from_dict({"target": cfg.target}, plv_cfg)
    objective = PLVObjective(plv_cfg, out / "plv", progress)
    try:
        for k, c in enumerate(rows):
            trial = objective(instance_domain({**exp.proxy, **c.theta}, plv_cfg.width, plv_cfg.height))
            c.plv, c.plv_low, c.plv_high = trial.plv.value, trial.interval.low, trial.interval.high
            c.plv_label, c.reached, c.zero_shot = trial.interval.label(), trial.reached_share, trial.zero_shot
            if progress:
                progress("PLV candidates", k + 1, len(rows))
        _, expert, reference = objective.target()
        t_cost = trial.plv.target_cost
    finally:
        objective.close()
    return _choice(rows, labels, best, plausible, tgt, exp, len(plv_cfg.seeds), reference, t_cost,
                   {"expert": expert, "plv_config": plv_cfg.to_dict(), **episodes})


@dataclass
class EpisodeScores:
    """Every episode's task scores behind PRPV: per agent (episodes × metrics) on the target and replayed in each
    candidate θ (episode i of a replay replays the target's episode i). Kept in the result (choice.json), so that
    the picks can be recomputed from what is shipped (results/, :mod:`proxybench.experiments.evidence`)."""

    target: dict[str, np.ndarray]
    candidates: dict[str, dict[str, np.ndarray]]
    metrics: tuple[str, ...]

    def to_dict(self) -> dict[str, Any]:
        as_lists = {a: np.asarray(v, float).tolist() for a, v in self.target.items()}
        return {"metrics": list(self.metrics), "target": as_lists,
                "candidates": {c: {a: np.asarray(v, float).tolist() for a, v in by.items()}
                               for c, by in self.candidates.items()}}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> EpisodeScores:
        arrays = {a: np.asarray(v, float) for a, v in d["target"].items()}
        return cls(arrays, {c: {a: np.asarray(v, float) for a, v in by.items()} for c, by in d["candidates"].items()},
                   tuple(d["metrics"]))


def prpv_of_candidates(rows: list[Candidate], scores: EpisodeScores, n_boot: int, seed: int) -> tuple[int, list[int]]:
    """Each candidate's PRPV with its order range and its paired difference to the lowest (set on ``rows``); the
    lowest one's index and the candidates the data cannot tell from it. A pure function of the episode scores."""
    higher = tuple(METRICS[m].higher_is_better for m in scores.metrics)
    for c in rows:
        e = usefulness(PairedResults(scores.candidates[c.label], scores.target, higher, scores.metrics),
                       n_boot=n_boot, seed=seed)["prpv"]
        c.prpv, c.prpv_low, c.prpv_high = e.value, e.low, e.high
    labels = [c.label for c in rows]
    samples = paired_prpv_samples(scores.target, [scores.candidates[lb] for lb in labels], higher, n_boot=n_boot,
                                  seed=seed)
    best, _, plausible = lowest_claim(labels, [c.prpv for c in rows], samples)
    for j, c in enumerate(rows):
        d = compare_paired(labels, [r.prpv for r in rows], samples, j, best).delta
        c.delta = (d.value, d.low, d.high)
    return best, list(plausible)


def _choice(rows: list[Candidate], labels: list[str], best: int, plausible: list[int], tgt: Any, exp: Any,
            seeds: int, reference: float, t_cost: float | None, extra: dict[str, Any]) -> ChoiceResult:
    """Both picks and their tied sets, once every candidate has its PRPV and its PLV."""
    plv_pick, plv_tied = plv_picks(rows)
    return ChoiceResult(rows, labels[best], [labels[j] for j in plausible], plv_pick, plv_tied,
                        tgt.info.statement, exp.agent_labels, exp.episode_count, seeds, reference, t_cost,
                        {"map": exp.map, "seconds": exp.seconds, "metrics": list(exp.metrics), **extra})


def plv_picks(rows: list[Candidate]) -> tuple[str | None, list[str]]:
    """argmax PLV (None when no candidate reaches P) and the candidates whose interval reaches the best one's."""
    reached = [c for c in rows if c.plv is not None]
    plv_best = max(reached, key=lambda c: c.plv) if reached else None
    if plv_best is None:
        return None, []
    return plv_best.label, [
        c.label for c in rows if c is plv_best or (c.plv_high is not None and plv_best.plv_low is not None
                                                   and c.plv_high >= plv_best.plv_low)
        or (c.plv_high is not None and plv_best.plv_low is None)]


def recompute_choice(shipped: dict[str, Any], scores: EpisodeScores) -> ChoiceResult:
    """A finished comparison (choice.json) recomputed: PRPV, its intervals and both picks from the episode scores,
    PLV as the run measured it (its networks are not shipped; a PLV run is shipped and rebuilt on its own)."""
    keep = {f for f in Candidate.__dataclass_fields__ if f.startswith("plv") or f in ("label", "theta", "reached",
                                                                                       "zero_shot")}
    rows = [Candidate(**{k: v for k, v in c.items() if k in keep}) for c in shipped["candidates"]]
    extra = shipped.get("extra") or {}
    best, plausible = prpv_of_candidates(rows, scores, int(extra["n_boot"]), int(extra["seed"]))
    plv_pick, plv_tied = plv_picks(rows)
    labels = [c.label for c in rows]
    return ChoiceResult(rows, labels[best], [labels[j] for j in plausible], plv_pick, plv_tied, shipped["target"],
                        list(shipped["agents"]), int(shipped["episodes"]), int(shipped["plv_seeds"]),
                        float(shipped["reference"]), shipped.get("target_samples"), dict(extra))


def instance_theta(spec: str) -> dict[str, float] | None:
    """θ of a PLV proxy given as an instance (``proxy:camera_pitch=3``, ``proxy`` alone: the nominal); None for a
    family (``randomized``, a family file), which PRPV cannot replay as one θ.

    >>> instance_theta("proxy:camera_pitch=3,trim=0.1")
    {'camera_pitch': 3.0, 'trim': 0.1}
    >>> instance_theta("randomized") is None
    True
    """
    if spec == "proxy":
        return {}
    if not spec.startswith("proxy:"):
        return None
    try:
        return {k: float(v) for k, _, v in (item.partition("=") for item in spec.removeprefix("proxy:").split(","))}
    except ValueError:
        return None


def _same_theta(a: dict[str, float], b: dict[str, float]) -> bool:
    full_a, full_b = {**NOMINAL, **a}, {**NOMINAL, **b}
    return all(np.isclose(float(full_a.get(k, np.nan)), float(full_b.get(k, np.nan))) for k in {*a, *b})


def run_candidates(folder: Path) -> list[tuple[str, dict[str, float]]]:
    """The candidates a finished PLV run offers: its instance proxies, labelled as :func:`candidates_of` labels."""
    from proxybench.experiments.plv.stored import StoredRunError, load_plv_run

    try:
        res = load_plv_run(folder)
    except StoredRunError as exc:
        raise ConfigError(f"plv.from_run: {exc}") from None
    out: dict[str, tuple[str, dict[str, float]]] = {}
    for spec in res.config.proxies.values():
        theta = instance_theta(spec)
        if theta is None:
            continue  # a family: no one θ to replay the agents on
        label = "nominal" if _same_theta(theta, {}) else ",".join(f"{k}={v:g}" for k, v in sorted(theta.items()))
        out.setdefault(label, (label, theta))
    if not out:
        raise ConfigError(f"plv.from_run: {folder} has no instance proxy (proxy:NAME=VALUE) to compare PRPV on")
    return list(out.values())


def _plv_from_run(rows: list[Candidate], folder: Path, target: str) -> tuple[int, float, float | None,
                                                                              dict[str, Any]]:
    """Each candidate's PLV from a finished ``proxybench plv`` run (its --out folder or a shipped results/NAME):
    the proxy of that run with the candidate's θ, else ConfigError naming the candidate. The run's target must be
    this study's (PLV and PRPV must answer for one target)."""
    from proxybench.experiments.plv.measures import summarize
    from proxybench.experiments.plv.stored import StoredRunError, load_plv_run

    try:
        res = load_plv_run(folder)
    except StoredRunError as exc:
        raise ConfigError(f"plv.from_run: {exc}") from None
    if res.config.target != target:
        raise ConfigError(f"plv.from_run: {folder}'s PLV was measured on target {res.config.target!r}, this study's "
                          f"target is {target!r}")
    s = summarize(res)
    for c in rows:
        match = [r for r in s.rows if (th := instance_theta(str(r.spec))) is not None and _same_theta(th, c.theta)]
        if not match:
            have = ", ".join(f"{r.proxy} ({r.spec})" for r in s.rows)
            raise ConfigError(f"plv.from_run: {folder} has no proxy with θ {c.label} (it has {have}); sweep only "
                              "its proxies' θ or leave the sweep out")
        r = match[0]
        c.plv, c.plv_low, c.plv_high = r.plv, r.plv_low, r.plv_high
        c.plv_label = r.plv_ci or r.plv_label
        c.reached, c.zero_shot = float(r.reached_share or 0.0), r.zero_shot
    return (len(res.config.seeds), s.reference, s.target_cost,
            {"expert": res.expert_score, "plv_config": res.config.to_dict(), "plv_from_run": str(folder)})
