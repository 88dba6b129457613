"""What every target kind gives an experiment: its episodes (agent, id, seed, start pose) and scores.

The kinds (:mod:`.spec`: the reality model and a recorded directory; :mod:`.robot`: a robot node) build on
these types; :func:`~.spec.open_target` picks the kind a user's text names.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.domain.kinds import DomainKind
from proxybench.domain.params import DomainParams
from proxybench.runner.backends import Backend
from proxybench.runner.jobs import AgentSpec, Job, JobResult

__all__ = ["Progress", "Target", "TargetEpisode", "TargetInfo", "TargetRun", "by_agent", "episode_seed"]

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

    def run(self, agents: list[AgentSpec], *, map_name: str, seconds: float, episodes: int, seed: int,
            metrics: tuple[str, ...], image_size: tuple[int, int], run_dir: str | Path,
            backend: Backend | None = None, progress: Progress | None = None) -> TargetRun:
        raise NotImplementedError


def by_agent(jobs: list[Job], results: list[JobResult], metrics: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Per agent: the (episodes × metrics) scores of its jobs, in job order."""
    by: dict[str, list[list[float]]] = {}
    for job, r in zip(jobs, results, strict=True):
        by.setdefault(job.agent.label, []).append([r.scores[m] for m in metrics])
    return {a: np.asarray(v, dtype=float) for a, v in by.items()}
