"""``rank`` as a study: the target's episodes of K agents, the proxy replaying them and running its own, then every
pair decided (:mod:`proxybench.usefulness.ranking`).

Fixed mode: the target's ``--episodes`` per agent, all at once. Sequential mode (``--sequential``): a pilot of
``--episodes`` per agent, then one target episode at a time for the agent in the most open pairs (among those
with the fewest episodes, so pairs stay paired), until every pair is decided or ``--budget`` is spent; the
intervals are anytime-valid, so stopping there (or at Ctrl-C) keeps the guarantee. Every episode is cached in
``OUT/runs``: a run that was interrupted replays the same choices from the cache and goes on.

The proxy replays each target episode (same agent, id, seed and start pose: its paired prediction) and runs
``--proxy-episodes`` of its own per agent, ids from :data:`PROXY_ONLY_FROM`, starts drawn from the simulator's
start distribution: prediction-powered inference assumes the target's starts are drawn that way too.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.domain.kinds import DomainKind
from proxybench.experiments.baselines import NOMINAL
from proxybench.experiments.config import COMMAND_DEFAULTS, ConfigError, Experiment, resolve
from proxybench.experiments.predictivity.run import proxy_jobs
from proxybench.experiments.proxies import proxy_domain
from proxybench.experiments.rank.config import RankConfig, proxy_theta
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import DomainSpec, Job, JobResult
from proxybench.runner.starts import start_poses
from proxybench.runner.sweep import run_jobs
from proxybench.targets.base import Target, TargetInfo, TargetRun, episode_seed
from proxybench.tasks.metrics import METRICS
from proxybench.usefulness.bradley_terry import RelativeScore
from proxybench.usefulness.indifference import semiorder_tolerances
from proxybench.usefulness.ranking import Ranking, RankingError, rank

__all__ = ["PROXY_ONLY_FROM", "RankResult", "Step", "measure_rank", "run_rank", "scores_of_jobs", "scores_of_target"]

Progress = Callable[[str, int, int], None]
#: the first id of the proxy's own episodes (no target episode has an id this large)
PROXY_ONLY_FROM = 100_000
Table = dict[str, dict[int, np.ndarray]]
#: a metric's Bradley–Terry scores: with the proxy as predictor, the proxy's weight λ, from the target alone
BTScores = tuple[tuple[RelativeScore, ...], float, tuple[RelativeScore, ...]]


@dataclass(frozen=True)
class Step:
    """One episode of the sequential mode: which agent ran which episode, with how many pairs open before it."""

    agent: str
    episode: int
    open_pairs: int


@dataclass
class RankResult:
    """The ranking, what it was computed from, and (sequential mode) the episodes it chose."""

    ranking: Ranking
    experiment: Experiment
    target: TargetInfo
    theta: dict[str, Any]
    theta_source: str
    tolerances: tuple[float, ...]
    target_episodes: dict[str, int]
    proxy_paired: int
    proxy_only: int
    steps: list[Step] = field(default_factory=list)
    stopped: str = "fixed"  # fixed | settled (every pair decided) | budget
    notes: list[str] = field(default_factory=list)
    wall_s: float = 0.0
    target_table: Table = field(default_factory=dict, repr=False)  # agent → episode id → scores (what was decided on)
    proxy_table: Table = field(default_factory=dict, repr=False)  # the proxy's, paired ids and its own (ids ≥ 100,000)
    #: metric → Bradley–Terry scores relative to the first agent: (with the proxy as predictor, its λ), target alone
    bradley_terry: dict[str, BTScores] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """rank.json: the level, the error control in words, every pair with and without the proxy, the episodes."""
        r = self.ranking
        return {"alpha": r.alpha, "error_control": r.error_control, "sequential": r.sequential,
                "target": {"kind": self.target.kind.value, "statement": self.target.statement,
                           "simulated": self.target.simulated},
                "agents": list(r.agents), "metrics": list(r.metrics), "tolerances": list(self.tolerances),
                "proxy": {"theta": self.theta, "source": self.theta_source},
                "pairs": [p.to_dict() for p in r.pairs], "target_only": [p.to_dict() for p in r.target_only],
                "decided": {"with_proxy": r.decided(), "target_only": r.decided(False),
                            "of": len(r.pairs)},
                "rank_sets": {m: {a: list(v) for a, v in s.items()} for m, s in r.rank_sets.items()},
                "episodes": {"target": sum(self.target_episodes.values()), "target_per_agent": self.target_episodes,
                             "proxy_paired": self.proxy_paired, "proxy_only": self.proxy_only},
                "stopped": self.stopped, "steps": [s.__dict__ for s in self.steps], "notes": self.notes,
                "bradley_terry": {m: {"reference": with_[0].agent, "weight": lam,
                                      "with_proxy": [[x.agent, x.score, x.lo, x.hi] for x in with_],
                                      "target_only": [[x.agent, x.score, x.lo, x.hi] for x in alone]}
                                  for m, (with_, lam, alone) in self.bradley_terry.items()},
                "wall_s": round(self.wall_s, 1)}


def scores_of_target(tgt: TargetRun) -> Table:
    """agent → episode id → scores, from a target run."""
    out: Table = {a: {} for a in tgt.results}
    for a, rows in tgt.results.items():
        for e, row in zip(tgt.episodes_of(a), rows, strict=True):
            out[a][e.episode] = np.asarray(row, float)
    return out


def scores_of_jobs(jobs: list[Job], results: list[JobResult], metrics: tuple[str, ...]) -> Table:
    """agent → episode id → scores, from proxy jobs and their results."""
    out: Table = {}
    for j, r in zip(jobs, results, strict=True):
        out.setdefault(j.agent.label, {})[j.episode] = np.array([r.scores[m] for m in metrics], float)
    return out


def measure_rank(exp: Experiment, target: Table, proxy: Table | None, tolerances: tuple[float, ...], alpha: float,
                 *, sequential: bool = False, horizon: float = 100.0) -> Ranking:
    """The ranking of ``target``'s agents with ``proxy`` as the predictor (runs no episode); bad input is a
    ConfigError naming the value."""
    higher = [METRICS[m].higher_is_better for m in exp.metrics]
    try:
        return rank(target, proxy, exp.metrics, higher, tolerances, alpha, sequential=sequential, horizon=horizon)
    except RankingError as exc:
        raise ConfigError(str(exc)) from None


def _tolerances(exp: Experiment, given: dict[str, float]) -> tuple[float, ...]:
    unknown = sorted(set(given) - set(exp.metrics))
    if unknown:
        raise ConfigError(f"tolerance: {', '.join(unknown)}: not a metric of this ranking ({', '.join(exp.metrics)})")
    return semiorder_tolerances(exp.metrics, exp.seconds, overrides=dict(given))


def _proxy_only_jobs(exp: Experiment, dom: DomainSpec, count: int) -> list[Job]:
    ids = list(range(PROXY_ONLY_FROM, PROXY_ONLY_FROM + count))
    seeds = [episode_seed(exp.seed, e) for e in ids]
    poses = start_poses(exp.map, seeds) if count else []
    return [Job(a, dom, exp.map, e, s, exp.seconds, pose=p, metrics=exp.metrics)
            for a in exp.agents for e, s, p in zip(ids, seeds, poses, strict=True)]


def run_rank(cfg: RankConfig, out: str | Path, backend: Backend | None = None, progress: Progress | None = None, *,
             quick: bool = False, target: Target | None = None) -> RankResult:
    """Run (or resume from ``out/runs``) the target's and the proxy's episodes and decide every pair."""
    t0 = time.perf_counter()
    out, backend = Path(out), backend or InlineBackend()
    defaults = COMMAND_DEFAULTS[("rank", quick)]
    exp, target = resolve(cfg, "rank", quick=quick, work_dir=out / "agents", target=target)
    if len(exp.agents) < 2:
        raise ConfigError(f"agents: ranking needs at least 2, got {len(exp.agents)} ({exp.agent_labels[0]})")
    tol = _tolerances(exp, cfg.tolerance)
    theta, source = proxy_theta(cfg)
    dom = proxy_domain(exp.image_size, exp.proxy, theta, "param", NOMINAL)
    n_only = defaults["proxy_episodes"] if cfg.proxy_episodes is None else cfg.proxy_episodes
    run_dir = out / "runs"
    run_kw = dict(map_name=exp.map, seconds=exp.seconds, seed=exp.seed, metrics=exp.metrics,
                  image_size=exp.image_size, run_dir=run_dir, backend=backend)
    notes = _notes(target, n_only)
    # the target's episodes first: a recording that lacks them fails before any proxy episode runs
    if cfg.sequential:
        live = _Sequential(target, exp, dom, run_kw, run_dir, backend, progress)
        live.pilot()
    else:
        tgt = target.run(exp.agents, episodes=exp.episodes, progress=progress, **run_kw)
    only_jobs = _proxy_only_jobs(exp, dom, n_only)
    only = run_jobs(only_jobs, run_dir, backend, progress=_bar(progress, "proxy-only episodes")).results
    proxy_only = scores_of_jobs(only_jobs, only, exp.metrics)
    if cfg.sequential:
        ranking, steps, stopped = live.run(proxy_only, tol, cfg.alpha, cfg.budget or defaults["budget"])
        tgt_scores, paired = live.target, live.paired
    else:
        jobs = proxy_jobs(exp, tgt, dom)
        res = run_jobs(jobs, run_dir, backend, progress=_bar(progress, "proxy episodes")).results
        tgt_scores, paired = scores_of_target(tgt), scores_of_jobs(jobs, res, exp.metrics)
        ranking = measure_rank(exp, tgt_scores, _merge(paired, proxy_only) if n_only else None, tol, cfg.alpha)
        steps, stopped = [], "fixed"
    proxy = _merge(paired, proxy_only)
    return RankResult(ranking, exp, target.info(), theta, source, tol, {a: len(v) for a, v in tgt_scores.items()},
                      sum(len(v) for v in paired.values()), sum(len(v) for v in proxy_only.values()), steps, stopped,
                      notes, time.perf_counter() - t0, tgt_scores, proxy,
                      bradley_terry_of(exp, tgt_scores, proxy if n_only else None, tol))


def bradley_terry_of(exp: Experiment, target: Table, proxy: Table | None,
                     tolerances: tuple[float, ...]) -> dict[str, BTScores]:
    """Per metric: Bradley–Terry scores with the proxy as predictor (PPI++; its λ) and from the target alone."""
    from proxybench.usefulness.bradley_terry import ppi_bradley_terry

    out = {}
    for m, name in enumerate(exp.metrics):
        def column(t: Table) -> dict[str, dict[int, float]]:
            return {a: {e: float(v[m]) for e, v in eps.items()} for a, eps in t.items()}  # noqa: B023

        higher, eps = METRICS[name].higher_is_better, tolerances[m]
        with_, lam = ppi_bradley_terry(column(target), column(proxy) if proxy else None, higher, eps)
        alone, _ = ppi_bradley_terry(column(target), None, higher, eps)
        out[name] = (with_, lam, alone)
    return out


def _bar(progress: Progress | None, what: str):
    return (lambda done, total, _r: progress(what, done, total)) if progress else None


def _merge(a: Table, b: Table) -> Table:
    return {k: {**a.get(k, {}), **b.get(k, {})} for k in {*a, *b}}


def _notes(target: Target, n_only: int) -> list[str]:
    notes = []
    if n_only == 0:
        notes.append("no proxy-only episodes (--proxy-episodes 0): the decisions use the target alone")
    if target.kind is DomainKind.RECORDED and n_only:
        notes.append("the proxy's own episodes start where the simulator's start distribution puts them; the "
                     "guarantee assumes the recording's starts were drawn the same way (as `proxybench target "
                     "record` draws them)")
    return notes


class _Sequential:
    """The sequential mode's loop: the target's episodes so far and the proxy's paired ones."""

    def __init__(self, target: Target, exp: Experiment, dom: DomainSpec, run_kw: dict[str, Any], run_dir: Path,
                 backend: Backend, progress: Progress | None):
        if not isinstance(exp.episodes, int):
            raise ConfigError("episodes: the sequential mode's pilot is a count (it adds the next ids), got ids")
        self.target_, self.exp, self.dom, self.run_kw = target, exp, dom, run_kw
        self.run_dir, self.backend, self.progress = run_dir, backend, progress
        self.specs = {a.label: a for a in exp.agents}
        self.target: Table = {a: {} for a in self.specs}
        self.paired: Table = {a: {} for a in self.specs}

    def _add(self, tgt: TargetRun) -> None:
        jobs = proxy_jobs(self.exp, tgt, self.dom)
        res = run_jobs(jobs, self.run_dir, self.backend).results
        for a, eps in scores_of_target(tgt).items():
            self.target[a].update(eps)
        for a, eps in scores_of_jobs(jobs, res, self.exp.metrics).items():
            self.paired[a].update(eps)

    def pilot(self) -> None:
        """The pilot: ``--episodes`` per agent, and the proxy's replays of them."""
        self._add(self.target_.run(self.exp.agents, episodes=self.exp.episodes, progress=self.progress, **self.run_kw))

    def run(self, proxy_only: Table, tol: tuple[float, ...], alpha: float,
            budget: int) -> tuple[Ranking, list[Step], str]:
        """After :meth:`pilot`: one episode at a time until every pair is decided or ``budget`` is spent."""
        exp, pilot = self.exp, int(self.exp.episodes)  # type: ignore[arg-type]
        horizon = pilot + budget / len(exp.agents)
        steps: list[Step] = []
        limit = self.target_.n_episodes
        while True:
            proxy = _merge(self.paired, proxy_only) if proxy_only else None
            ranking = measure_rank(exp, self.target, proxy, tol, alpha, sequential=True, horizon=horizon)
            open_ = {(p.a, p.b) for p in ranking.pairs if p.decision == "undecided"}
            total = len(ranking.pairs) // len(exp.metrics)
            if self.progress:
                self.progress("pairs decided", total - len(open_), total)
                self.progress("sequential target episodes", len(steps), budget)
            counts = {a: len(v) for a, v in self.target.items()}
            pick = _next_agent(open_, counts, limit)
            if not open_ or len(steps) >= budget or pick is None:
                return ranking, steps, "settled" if not open_ else "budget"
            e = counts[pick]
            self._add(self.target_.run([self.specs[pick]], episodes=(e,), **self.run_kw))
            steps.append(Step(pick, e, len(open_)))


def _next_agent(open_: set[tuple[str, str]], counts: dict[str, int], limit: int | None) -> str | None:
    """The agent whose next episode extends the most open pairs (a pair grows when its agent with fewer episodes
    runs); ties: the fewest episodes, then the name. None when no agent in an open pair can run another."""
    gain: dict[str, int] = {}
    for a, b in open_:
        for x, y in ((a, b), (b, a)):
            if counts[x] <= counts[y] and (limit is None or counts[x] < limit):
                gain[x] = gain.get(x, 0) + 1
    if not gain:
        return None
    return min(gain, key=lambda a: (-gain[a], counts[a], a))
