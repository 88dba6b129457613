"""Score a batched policy in a domain: all episodes side by side in one simulator, one network call per frame.

The episode engine (``runner.rollout``) on a :class:`~proxybench.runner.episode.SimPlant` with a
:class:`~proxybench.runner.rollout.BatchPolicy`: each robot of the batch runs exactly the episode
``run_episode`` would run for the same seed: it starts from the evaluation start distribution, sees a
frame every 1/frame_rate s (the rendered pixels, no JPEG round trip), and stops when it leaves the road
or hits an object of the map. Its physics-rate trajectory is then scored by the same task metric code as
every other run (by default the thesis' lane score: episode time, −1 per second with one wheel out of the
lane, −2 per second with both out). One network call serves the whole batch.

The PLV experiment caches these scores itself (per rung, next to the checkpoint), so they do not go
through the runner's job cache.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from proxybench.domain.simulator import Simulator
from proxybench.learning.domains import Domain
from proxybench.learning.expert import expert_actions
from proxybench.runner.collect import Policy
from proxybench.runner.episode import SimPlant
from proxybench.runner.rollout import BatchPolicy, rollout
from proxybench.tasks.metrics import METRICS

__all__ = ["EvalConfig", "EvalResult", "evaluate_expert", "evaluate_policy"]


@dataclass(frozen=True)
class EvalConfig:
    """Evaluation episodes: episode e uses simulator seed ``seed + e`` (never a data-collection seed)."""

    episodes: int = 6
    seconds: float = 30.0
    map: str = "loop_3x3"
    seed: int = 100_000
    metric: str = "lane_score"


@dataclass
class EvalResult:
    """Per-episode scores and how each episode ended."""

    scores: list[float]
    terminations: list[str]

    @property
    def mean(self) -> float:
        return float(np.mean(self.scores))


def evaluate_policy(policy: Policy, domain: Domain, cfg: EvalConfig | None = None) -> EvalResult:
    """Run ``cfg.episodes`` episodes of ``policy`` in ``domain`` at once; score each with ``cfg.metric``."""
    cfg = cfg or EvalConfig()
    return _evaluate(BatchPolicy(lambda images, plant: policy(images), cfg.episodes, "network"), domain, cfg,
                     render=True)


def evaluate_expert(domain: Domain, cfg: EvalConfig | None = None) -> EvalResult:
    """The privileged expert (pure pursuit on the true pose) on the same episodes: the teacher's own score."""
    cfg = cfg or EvalConfig()
    return _evaluate(BatchPolicy(lambda images, plant: expert_actions(plant.sim.lane), cfg.episodes, "expert",
                                 privileged=True), domain, cfg, render=False)


def _evaluate(policy: BatchPolicy, domain: Domain, cfg: EvalConfig, render: bool) -> EvalResult:
    """The engine's rollout on a simulator of ``cfg.episodes`` robots, each with its own draw of θ."""
    seeds = [cfg.seed + e for e in range(cfg.episodes)]
    thetas = [domain.sample(np.random.default_rng(s)) for s in seeds]
    sim = Simulator(cfg.map, thetas, render=render)
    trajs = rollout(SimPlant(sim), policy, seeds, cfg.seconds, camera=render,
                    metas=[{"domain": domain.name, "domain_kind": domain.kind}] * sim.n)
    metric = METRICS[cfg.metric]
    return EvalResult([metric(t) for t in trajs], [t.termination for t in trajs])
