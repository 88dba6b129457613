"""Sequential allocation of target episodes: spend them on the pairs of agents whose order is still open.

On a live target (the reality model, a robot node) the loop runs a pilot, then one batch of episodes at a
time through the runner (:func:`~proxybench.usefulness.stopping.run_until_settled`: the agents whose next
episode most raises the expected number of settled pairs), and stops when every pair on the target is settled
— ordered, or tied within the task's tolerance ε — or the budget is spent. The rule's error rate is checked
by simulation (docs/usefulness.md). Episode e of an agent gets the seed and the start pose that ``Target.run``
gives episode e, and is cached under the same key, so a later ``proxybench predictivity`` on the same run
directory re-uses every episode run here.

A recorded target cannot run episodes: ``proxybench plan`` prints which agents to record next instead.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
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
from proxybench.usefulness.stopping import Batch, run_until_settled

__all__ = ["SequentialResult", "run_sequential"]


@dataclass
class SequentialResult:
    """The target's episodes after the loop, how many each agent got, what each batch did and the decisions."""

    results: dict[str, np.ndarray]
    episodes: dict[str, int]
    metrics: tuple[str, ...]
    higher: tuple[bool, ...]
    run: TargetRun | None = None  # the same as a TargetRun (episodes with seeds and poses): proxies can replay it
    history: list[Batch] = field(default_factory=list)  # per batch: agents run, pairs still open (as of the last look)
    stopped: str = "budget"  # "settled" (no open pair left) | "budget"
    ran: int = 0  # episodes run now (not from the cache)
    open_after_pilot: int = 0  # target pairs whose order the pilot left open
    decisions: dict[tuple[str, str], str] = field(default_factory=dict)  # the better agent | tie | incomparable | open
    tolerances: tuple[float, ...] = ()
    looks: int = 1

    def open_pairs(self) -> list[tuple[str, str]]:
        """The target's pairs of agents whose order is still open."""
        return [p for p, d in self.decisions.items() if d == "open"]


def run_sequential(target: Target, agents: list[AgentSpec], *, map_name: str, seconds: float, seed: int,
                   metrics: tuple[str, ...], image_size: tuple[int, int], run_dir: str | Path,
                   backend: Backend | None = None, pilot: int = 3, budget: int = 20, batch: int = 2,
                   level: float = 0.95, tolerances: Sequence[float] | None = None, correct: bool = True,
                   progress: Callable[[str, int, int], None] | None = None) -> SequentialResult:
    """Run ``pilot`` episodes per agent on the live ``target``, then up to ``budget`` more, ``batch`` at a time,
    until every pair is settled (ε per metric: ``tolerances``, default 0)."""
    if not hasattr(target, "domain"):
        raise TargetError(f"a {target.kind} target cannot run more episodes; `proxybench plan` prints which agents "
                          "to record next")
    backend = backend or InlineBackend()
    higher = tuple(METRICS[m].higher_is_better for m in metrics)
    tol = tuple(tolerances) if tolerances is not None else (0.0,) * len(metrics)
    tgt = target.run(agents, map_name=map_name, seconds=seconds, episodes=pilot, seed=seed, metrics=metrics,
                     image_size=image_size, run_dir=run_dir, backend=backend, progress=progress)
    counts = {a.label: pilot for a in agents}
    specs = {a.label: a for a in agents}
    seeds = [episode_seed(seed, e) for e in range(pilot + budget)]
    poses = start_poses(map_name, seeds)
    dom = target.domain(image_size)
    ran = [tgt.ran]

    def fetch(picks: list[str]) -> list[np.ndarray]:
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
        ran[0] += sweep.ran
        return [np.array([r.scores[m] for m in metrics], float) for r in sweep.results]

    res = run_until_settled({a: np.asarray(v, float) for a, v in tgt.results.items()}, fetch, higher,
                            tolerances=tol, budget=budget, batch=batch, level=level, correct=correct,
                            progress=(lambda d, t: progress("sequential episodes", d, t)) if progress else None)
    out = SequentialResult(res.results, dict(counts), tuple(metrics), higher, history=res.history,
                           stopped=res.stopped, ran=ran[0], open_after_pilot=res.open_after_pilot,
                           decisions=res.decisions, tolerances=tol, looks=res.rule.looks)
    episodes = [TargetEpisode(a.label, e, seeds[e], poses[e]) for a in agents for e in range(counts[a.label])]
    out.run = TargetRun(tgt.info, tgt.map, tgt.seconds, tgt.metrics, episodes, res.results, tgt.truth, tgt.params,
                        out.ran)
    return out
