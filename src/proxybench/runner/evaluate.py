"""Evaluate agents on a benchmark file: episodes → results → aggregates → leaderboard (semiorder).

This is the engine behind ``proxybench evaluate``; it returns data and writes the run directory, the
CLI only prints.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from proxybench.domain.kinds import DomainKind
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job
from proxybench.runner.streams import StreamSpec
from proxybench.runner.sweep import SweepResult, results_frame, run_jobs
from proxybench.tasks.benchmark import NAMED_DOMAINS, Benchmark, BenchmarkError
from proxybench.tasks.scoring import Rank, leaderboard

__all__ = ["Evaluation", "benchmark_domain", "evaluate_benchmark", "with_reruns"]


@dataclass
class Evaluation:
    """The leaderboard, the per-agent aggregates it was computed from, and the sweep behind them."""

    benchmark: Benchmark
    ranks: list[Rank]
    aggregates: object  # pandas DataFrame (one row per agent)
    sweep: SweepResult
    refused: dict[str, str]


def benchmark_domain(bench: Benchmark, named: str | None = None) -> DomainSpec:
    """The domain a benchmark runs in (or the named domain that replaces it), with the benchmark's rates."""
    if named is not None:
        if named not in NAMED_DOMAINS:
            raise BenchmarkError(f"unknown domain {named!r}; known: {', '.join(NAMED_DOMAINS)}")
        params = NAMED_DOMAINS[named]().replace(physics_rate=bench.physics_rate, frame_rate=bench.frame_rate)
        return DomainSpec(named, params, _kind(named))
    name = bench.domain.named or "benchmark"
    return DomainSpec(name, bench.domain_params(), _kind(bench.domain.named))


def _kind(named: str | None) -> DomainKind:
    """The kind of a named domain: the reality model, else a simulation."""
    return DomainKind.REALITY_MODEL if named == "reality" else DomainKind.SIMULATION


def evaluate_benchmark(
    bench: Benchmark, agents: Sequence[AgentSpec], run_dir: str | Path, backend: Backend | None = None, *,
    domain: str | DomainSpec | None = None, privileged: Callable[[AgentSpec], bool] | None = None,
    progress: Callable[[int, int], None] | None = None, streams: StreamSpec | None = None,
    episodes: Collection[int] | None = None,
) -> Evaluation:
    """Run every admitted agent on every episode of ``bench``; rank them by the benchmark's criteria.

    ``domain``: where the episodes run: the benchmark's own domain (None), a named domain that replaces it
    (``reality``, ...), or any :class:`~.jobs.DomainSpec`, e.g. a robot node (``DomainSpec.robot``). Every
    domain's episodes go through the same jobs, cache and resume, with the benchmark's starts and routes.
    Agents that the benchmark does not admit (privileged ones on a camera-only benchmark) are left out
    and listed in ``refused`` with the reason. ``streams``: fixed cameras (a lab's watchtowers) recorded in every
    episode, beside its trajectory in the run directory (``JobResult.streams``). ``episodes``: run only the
    episodes of these indices (an Autolab's re-run of an invalid episode: its own seed, start and route), the
    evaluation then holding theirs alone (:func:`with_reruns` puts them into the whole split's).
    """
    refused: dict[str, str] = {}
    admitted = []
    for a in agents:
        if bench.camera_only and privileged is not None and privileged(a):
            refused[a.label] = f"privileged (reads the true lane pose); {bench.name!r} admits camera-only agents"
        else:
            admitted.append(a)
    if not admitted:
        raise BenchmarkError(f"benchmark {bench.name!r}: no admitted agent ({'; '.join(refused.values())})")
    dom = domain if isinstance(domain, DomainSpec) else benchmark_domain(bench, domain)
    metrics = tuple(bench.metrics)
    npcs = bench.traffic()
    if dom.kind is DomainKind.ROBOT:
        if streams is not None:
            raise BenchmarkError("watchtower streams are simulated: they need a simulated domain, not a robot node")
        if npcs is not None and not npcs.empty:
            raise BenchmarkError(f"benchmark {bench.name!r} has npcs:, but a robot node drives one robot and no NPCs")
        npcs = None
    jobs = [Job(a, dom, bench.map, ep.index, ep.seed, bench.duration, ep.pose, bench.camera_only, metrics,
                route=ep.route, npcs=npcs, streams=streams)
            for a in admitted for ep in bench.episode_specs() if episodes is None or ep.index in episodes]
    sweep = run_jobs(jobs, run_dir, backend or InlineBackend(),
                     progress=(lambda d, t, _r: progress(d, t)) if progress else None)
    return _evaluation(bench, sweep, refused)


def _evaluation(bench: Benchmark, sweep: SweepResult, refused: dict[str, str]) -> Evaluation:
    """The aggregates and the leaderboard of a sweep's results."""
    from proxybench.tasks.aggregate import aggregate, scores_by_agent

    frame = results_frame(sweep.results)
    agg = aggregate(frame[["agent", "domain", "episode", "metric", "value"]], n_resamples=1000)
    ranks = leaderboard(scores_by_agent(agg), bench.criteria())
    return Evaluation(bench, ranks, agg, sweep, refused)


def with_reruns(ev: Evaluation, rerun: Evaluation) -> Evaluation:
    """``ev`` with the results of each (agent, episode) that ``rerun`` ran again replaced by the re-run's (an
    Autolab's retry of an invalid run: the last attempt is the episode's), aggregates and leaderboard recomputed;
    the sweep's costs are both sweeps'. ``ev`` itself is left as it was."""
    again = {(r.agent, r.episode): r for r in rerun.sweep.results}
    results = [again.pop((r.agent, r.episode), r) for r in ev.sweep.results]
    timings = dict(ev.sweep.timings)
    for k, v in rerun.sweep.timings.items():
        timings[k] = timings.get(k, 0.0) + v
    sweep = replace(ev.sweep, results=[*results, *again.values()], cached=ev.sweep.cached + rerun.sweep.cached,
                    ran=ev.sweep.ran + rerun.sweep.ran, wall_s=ev.sweep.wall_s + rerun.sweep.wall_s, timings=timings)
    return _evaluation(ev.benchmark, sweep, ev.refused)
