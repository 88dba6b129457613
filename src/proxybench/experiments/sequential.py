"""Sequential allocation of target episodes: spend them on the pairs of agents whose order is still open.

On a live target (the reality model, a robot node) the loop runs a pilot, then one batch of episodes at a
time through the runner; before each batch :func:`~proxybench.usefulness.plan.next_agents` picks the
agents whose next episode most raises the expected number of settled pairs (near ties). It stops when
every pair on the target is settled or the budget is spent. Episode e of an agent gets the seed and the
start pose that ``Target.run`` gives episode e, and is cached under the same key, so a later
``proxybench predictivity`` on the same run directory re-uses every episode run here.

A recorded target cannot run episodes: ``proxybench plan`` prints which agents to record next instead.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from proxybench.domain.events import Termination
from proxybench.runner.backends import Backend, InlineBackend
from proxybench.runner.jobs import AgentSpec, Job
from proxybench.runner.starts import start_poses
from proxybench.runner.sweep import run_jobs
from proxybench.targets.base import Target, TargetEpisode, TargetRun, episode_seed
from proxybench.targets.manifest import TargetError
from proxybench.tasks.metrics import METRICS
from proxybench.usefulness.plan import PairNeed, next_agents, pair_needs

__all__ = ["SequentialResult", "run_sequential"]


@dataclass
class SequentialResult:
    """The target's episodes after the loop, how many each agent got, and what each batch did."""

    results: dict[str, np.ndarray]
    episodes: dict[str, int]
    metrics: tuple[str, ...]
    higher: tuple[bool, ...]
    run: TargetRun | None = None  # the same as a TargetRun (episodes with seeds and poses): proxies can replay it
    history: list[dict] = field(default_factory=list)  # per batch: agents run, pairs still open after it
    stopped: str = "budget"  # "settled" (no open pair left) | "budget"
    ran: int = 0  # episodes run now (not from the cache)
    open_after_pilot: int = 0  # target pairs whose order the pilot left open

    def open_pairs(self, level: float = 0.95) -> list[PairNeed]:
        """The target's pairs of agents whose order is still open."""
        return [p for p in pair_needs(self.results, self.higher, self.metrics, level=level) if not p.settled]


def run_sequential(target: Target, agents: list[AgentSpec], *, map_name: str, seconds: float, seed: int,
                   metrics: tuple[str, ...], image_size: tuple[int, int], run_dir: str | Path,
                   backend: Backend | None = None, pilot: int = 3, budget: int = 20, batch: int = 2,
                   level: float = 0.95, progress: Callable[[str, int, int], None] | None = None) -> SequentialResult:
    """Run ``pilot`` episodes per agent on the live ``target``, then up to ``budget`` more, ``batch`` at a time,
    where :func:`~proxybench.usefulness.plan.next_agents` says they settle most."""
    if not hasattr(target, "domain"):
        raise TargetError(f"a {target.kind} target cannot run more episodes; `proxybench plan` prints which agents "
                          "to record next")
    backend = backend or InlineBackend()
    higher = tuple(METRICS[m].higher_is_better for m in metrics)
    tgt = target.run(agents, map_name=map_name, seconds=seconds, episodes=pilot, seed=seed, metrics=metrics,
                     image_size=image_size, run_dir=run_dir, backend=backend, progress=progress)
    results = {a: np.asarray(v, float) for a, v in tgt.results.items()}
    counts = {a.label: pilot for a in agents}
    specs = {a.label: a for a in agents}
    seeds = [episode_seed(seed, e) for e in range(pilot + budget)]
    poses = start_poses(map_name, seeds)
    dom = target.domain(image_size)
    out = SequentialResult(results, counts, tuple(metrics), higher, ran=tgt.ran)
    out.open_after_pilot = len(out.open_pairs(level))
    spent = 0
    while spent < budget:
        picks = next_agents(results, higher, k=min(batch, budget - spent), level=level)
        if not picks:
            out.stopped = "settled"
            break
        jobs = []
        for a in picks:
            e = counts[a]
            counts[a] += 1
            jobs.append(Job(specs[a], dom, map_name, e, seeds[e], seconds, pose=poses[e], metrics=metrics))
        sweep = run_jobs(jobs, run_dir, backend)
        failed = [r for r in sweep.results if r.termination is Termination.ROBOT_FAILURE]
        if failed:  # not the agent's fault, and not cached: stop, as a robot target's pilot does
            raise TargetError(f"target: the robot node failed on {len(failed)} episode(s) "
                              f"({failed[0].agent} episode {failed[0].episode}: {failed[0].message}); finished "
                              "episodes are cached, run again to go on")
        for job, r in zip(jobs, sweep.results, strict=True):
            row = np.array([[r.scores[m] for m in metrics]], float)
            results[job.agent.label] = np.vstack([results[job.agent.label], row])
        spent += len(jobs)
        out.ran += sweep.ran
        still = len(out.open_pairs(level))
        out.history.append({"agents": picks, "open_pairs": still})
        if progress:
            progress("sequential episodes", spent, budget)
        if still == 0:
            out.stopped = "settled"
            break
    else:
        if not next_agents(results, higher, k=1, level=level):
            out.stopped = "settled"
    episodes = [TargetEpisode(a.label, e, seeds[e], poses[e]) for a in agents for e in range(counts[a.label])]
    out.run = TargetRun(tgt.info, tgt.map, tgt.seconds, tgt.metrics, episodes, results, tgt.truth, tgt.params, out.ran)
    return out
