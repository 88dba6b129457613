"""Score a behaviour-cloning network, or the expert that taught it, in a domain: all episodes side by side in one
simulator, one network call per frame, through the runner's episode engine (:mod:`proxybench.runner.policy_eval`).

Each episode e of an :class:`EvalConfig` starts from simulator seed ``seed + e`` (never a data-collection seed)
with its own θ (a family's draw); on a robot node (``Domain.kind == "robot"``) the node's plant plays them one
after another from the starts those seeds draw; the network sees the node's frames brought to its size, the
expert reads the true lane pose the node serves.

The PLV experiment caches these scores itself (per rung, next to the checkpoint), so they do not go through the
runner's job cache.
"""

from __future__ import annotations

import contextlib

import numpy as np

from proxybench.learning.collection import Policy, robot_spec
from proxybench.learning.configs import EvalConfig
from proxybench.learning.domains import Domain
from proxybench.learning.expert import expert_actions
from proxybench.runner.plants import PlantPool
from proxybench.runner.policy_eval import EvalResult, frames_policy, score_episodes
from proxybench.runner.rollout import BatchPolicy, lane_rows

__all__ = ["EvalConfig", "EvalResult", "evaluate_expert", "evaluate_policy", "expert_policy"]


def expert_policy(n: int) -> BatchPolicy:
    """The privileged expert (pure pursuit on the true lane pose) as the engine's batched policy of n robots."""
    return BatchPolicy(lambda images, plant: expert_actions(lane_rows(plant)), n, "expert", privileged=True)


def evaluate_policy(policy: Policy, domain: Domain, cfg: EvalConfig | None = None,
                    pool: PlantPool | None = None) -> EvalResult:
    """Run ``cfg.episodes`` episodes of ``policy`` in ``domain`` at once; score each with ``cfg.metric``. A robot
    domain's node comes from ``pool`` (kept running there), else is started for this call."""
    return _evaluate(lambda n: frames_policy(policy, domain.image_size, n), domain, cfg or EvalConfig(), True, pool)


def evaluate_expert(domain: Domain, cfg: EvalConfig | None = None, pool: PlantPool | None = None) -> EvalResult:
    """The privileged expert on the same episodes: the teacher's own score."""
    return _evaluate(expert_policy, domain, cfg or EvalConfig(), False, pool)


def _evaluate(make, domain: Domain, cfg: EvalConfig, render: bool, pool: PlantPool | None) -> EvalResult:
    seeds = [cfg.seed + e for e in range(cfg.episodes)]
    meta = {"domain": domain.name, "domain_kind": domain.kind}
    common = {"map_": cfg.map, "render": render, "meta": meta}
    if domain.kind == "robot":
        with contextlib.ExitStack() as stack:
            plant = (pool or stack.enter_context(PlantPool())).robot(robot_spec(domain), cfg.map)
            return score_episodes(make, seeds, cfg.seconds, cfg.metric, plant=plant, **common)
    thetas = [domain.sample(np.random.default_rng(s)) for s in seeds]
    return score_episodes(make, seeds, cfg.seconds, cfg.metric, thetas=thetas, **common)
