"""What every target kind gives an experiment: its episodes (agent, id, seed, start pose) and scores.

The kinds (:mod:`.spec`: the reality model and a recorded directory; :mod:`.robot`: a robot node) build on
these types; :func:`~.spec.open_target` picks the kind a user's text names.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from proxybench.domain.kinds import DomainKind
from proxybench.domain.params import DomainParams
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job, JobResult
from proxybench.untrusted import repeated

if TYPE_CHECKING:  # the backends load the episode engine: not at import, so a config (and --help) stays light
    from proxybench.runner.backends import Backend

__all__ = ["Episodes", "Progress", "Target", "TargetEpisode", "TargetInfo", "TargetRun", "by_agent", "episode_count",
           "episode_ids", "episode_seed", "id_ranges", "live_run", "parse_episodes"]

Progress = Callable[[str, int, int], None]


def episode_seed(seed: int, episode: int) -> int:
    """The seed of episode ``episode`` of an experiment seeded ``seed`` (as every runner sweep uses)."""
    return seed * 10_000 + episode


@dataclass(frozen=True)
class TargetEpisode:
    """One target episode: whose, which, its seed and its start pose (None: drawn from the seed)."""

    agent: str
    episode: int
    seed: int
    pose: tuple[float, float, float] | None


@dataclass(frozen=True)
class TargetInfo:
    """What a target is, in words a report can print: ``kind`` (reality-model | recorded | robot),
    ``simulated`` (True, False, or None when proxybench cannot tell), a short ``label`` and a ``statement``."""

    kind: DomainKind
    simulated: bool | None
    label: str
    statement: str
    details: dict[str, Any] = field(default_factory=dict)


@dataclass
class TargetRun:
    """The target's side of an experiment: episodes (agent-major) and per-agent (episodes × metrics) scores."""

    info: TargetInfo
    map: str
    seconds: float
    metrics: tuple[str, ...]
    episodes: list[TargetEpisode]
    results: dict[str, np.ndarray]
    truth: dict[str, float] = field(default_factory=dict)
    params: DomainParams | None = None  # θ of a simulated target when known (POD needs it)
    ran: int = 0  # episodes simulated or driven now (not cached, not read from files)
    files: dict[tuple[str, int], str] = field(default_factory=dict)  # (agent, episode) → its trajectory file

    def episodes_of(self, agent: str) -> list[TargetEpisode]:
        return [e for e in self.episodes if e.agent == agent]


class Target:
    """Base of the three kinds. A recorded target fixes its map, length, agents and episodes; the others
    take them from the experiment."""

    kind: DomainKind  # each kind's own
    fixed_map: str | None = None
    fixed_seconds: float | None = None
    fixed_agents: list[str] | None = None
    n_episodes: int | None = None

    def info(self) -> TargetInfo:
        raise NotImplementedError

    def planned_poses(self, map_name: str, episodes: list[int], seeds: list[int]) -> list[Any]:
        """The start pose each episode is asked to begin at (None: wherever the target puts its robot): the pose
        each seed draws, unless the target knows its starts otherwise (a DTPS robot's pose file)."""
        from proxybench.runner.starts import start_poses

        return start_poses(map_name, seeds)

    def started_at(self, job: Job, result: JobResult) -> tuple[float, float, float] | None:
        """Where an episode the runner played began, for the proxies to replay it from: the pose it was asked to
        start at (a simulator or a robot node puts its robot there; a DTPS robot says where it stood)."""
        return job.pose

    def run(self, agents: list[AgentSpec], *, map_name: str, seconds: float, episodes: Episodes, seed: int,
            metrics: tuple[str, ...], image_size: tuple[int, int], run_dir: str | Path,
            backend: Backend | None = None, progress: Progress | None = None) -> TargetRun:
        """The target's episodes of ``agents``: ``episodes`` is a count (ids 0 … n−1) or the ids themselves
        (e.g. a held-out split ``5-9``); episode id e of a live target starts from ``episode_seed(seed, e)``."""
        raise NotImplementedError


#: which episodes: the first n ids, or these ids
Episodes = int | Sequence[int]


def episode_ids(episodes: Episodes) -> list[int]:
    """The ids ``episodes`` names: 0 … n−1 for a count, else the ids as given."""
    return list(range(episodes)) if isinstance(episodes, int) else [int(e) for e in episodes]


def episode_count(episodes: Episodes) -> int:
    """How many episodes per agent ``episodes`` names."""
    return episodes if isinstance(episodes, int) else len(episodes)


def parse_episodes(value: Any) -> Episodes:
    """A count or the ids of a split, as a user writes them: ``10`` (the first ten), ``"5-9"``, ``"0-4,7"``,
    ``[0, 2, 4]`` (ids). One id alone is ``"7-7"`` or ``[7]`` (a bare number is a count). A ValueError
    says what is wrong in the user's words (a fit / held-out split of one recording needs no copies)."""
    if isinstance(value, bool):
        raise ValueError(f"a count or ids such as 0-4,7, got {value!r}")
    if isinstance(value, int):
        return value
    if isinstance(value, str):
        text = value.strip()
        if text.isdigit():
            return int(text)
        ids: list[int] = []
        for part in (p.strip() for p in text.split(",")):
            lo, dash, hi = part.partition("-")
            if not (lo.strip().isdigit() and (not dash or hi.strip().isdigit())):
                raise ValueError(f"a count or ids such as 0-4,7, got {value!r} (at {part!r})")
            a, b = int(lo), int(hi) if dash else int(lo)
            if b < a:
                raise ValueError(f"the range {part!r} runs backwards")
            if b - a > 100_000:
                raise ValueError(f"the range {part!r} holds more than 100,000 episodes")
            ids.extend(range(a, b + 1))
        value = ids
    if isinstance(value, (list, tuple)):
        if not value:
            raise ValueError("no episode ids given")
        if not all(isinstance(e, int) and not isinstance(e, bool) and e >= 0 for e in value):
            raise ValueError(f"episode ids must be integers >= 0, got {list(value)[:5]!r}")
        if len(set(value)) != len(value):
            raise ValueError(f"episode ids repeat: {id_ranges(repeated(value))}")
        return tuple(value)
    raise ValueError(f"a count or ids such as 0-4,7, got {type(value).__name__}")


def id_ranges(ids: Sequence[int]) -> str:
    """Episode ids written as ranges: 0-4, 7."""
    out, run = [], []
    for e in sorted(ids):
        if run and e == run[-1] + 1:
            run.append(e)
            continue
        if run:
            out.append(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]))
        run = [e]
    if run:
        out.append(f"{run[0]}-{run[-1]}" if len(run) > 1 else str(run[0]))
    return ", ".join(out)


def live_run(target: Target, dom: DomainSpec, agents: list[AgentSpec], *, map_name: str, seconds: float,
             episodes: Episodes, seed: int, metrics: tuple[str, ...], run_dir: str | Path,
             backend: Backend | None, progress: Progress | None, stage: str = "target episodes"
             ) -> tuple[TargetRun, Any]:
    """The episodes of a target the runner plays (reality model, held-out model, robot node), through its jobs and
    cache: (the run, the sweep behind it). Every agent plays every id, from the start pose the target plans for
    it (:meth:`Target.planned_poses`: the one its seed draws); the proxies replay it from where it began
    (:meth:`Target.started_at`)."""
    from proxybench.runner.backends import InlineBackend
    from proxybench.runner.sweep import run_jobs

    ids = episode_ids(episodes)
    seeds = {e: episode_seed(seed, e) for e in ids}
    poses = dict(zip(ids, target.planned_poses(map_name, ids, [seeds[e] for e in ids]), strict=True))
    jobs = [Job(a, dom, map_name, e, seeds[e], seconds, pose=poses[e], metrics=metrics) for a in agents for e in ids]
    sweep = run_jobs(jobs, run_dir, backend or InlineBackend(),
                     progress=(lambda d, t, _r: progress(stage, d, t)) if progress else None)
    eps = [TargetEpisode(j.agent.label, j.episode, j.seed, target.started_at(j, r))
           for j, r in zip(jobs, sweep.results, strict=True)]
    files = {(j.agent.label, j.episode): r.trajectory for j, r in zip(jobs, sweep.results, strict=True)
             if r.trajectory}
    run = TargetRun(target.info(), map_name, seconds, metrics, eps, by_agent(jobs, sweep.results, metrics),
                    params=dom.params, ran=sweep.ran, files=files)
    return run, sweep


def by_agent(jobs: list[Job], results: list[JobResult], metrics: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Per agent: the (episodes × metrics) scores of its jobs, in job order."""
    by: dict[str, list[list[float]]] = {}
    for job, r in zip(jobs, results, strict=True):
        by.setdefault(job.agent.label, []).append([r.scores[m] for m in metrics])
    return {a: np.asarray(v, dtype=float) for a, v in by.items()}
