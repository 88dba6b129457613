"""Score a batched policy in a domain: all episodes side by side in one simulator, one network call per frame.

The episode engine (``runner.rollout``) on a :class:`~proxybench.runner.episode.SimPlant` with a
:class:`~proxybench.runner.rollout.BatchPolicy`: each robot of the batch runs exactly the episode
``run_episode`` would run for the same seed: it starts from the evaluation start distribution, sees a
frame every 1/frame_rate s (the rendered pixels, no JPEG round trip), and stops when it leaves the road
or hits an object of the map. Its physics-rate trajectory is then scored by the same task metric code as
every other run (by default the thesis' lane score: episode time, −1 per second with one wheel out of the
lane, −2 per second with both out). One network call serves the whole batch.

On a robot node (``Domain.kind == "robot"``) the same engine drives the node's :class:`RobotPlant`, one
episode at a time from the starts those seeds draw; the network sees the node's frames brought to its size,
the expert reads the true lane pose the node serves.

The PLV experiment caches these scores itself (per rung, next to the checkpoint), so they do not go
through the runner's job cache.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from proxybench.domain.simulator import Simulator
from proxybench.learning.configs import EvalConfig
from proxybench.learning.domains import Domain
from proxybench.learning.expert import expert_actions
from proxybench.runner.collect import Policy, lane_rows, robot_spec
from proxybench.runner.episode import SimPlant
from proxybench.runner.plants import PlantPool, fit_frames
from proxybench.runner.rollout import BatchPolicy, rollout
from proxybench.tasks.metrics import METRICS

__all__ = ["EvalConfig", "EvalResult", "evaluate_expert", "evaluate_policy"]


@dataclass
class EvalResult:
    """Per-episode scores and how each episode ended."""

    scores: list[float]
    terminations: list[str]

    @property
    def mean(self) -> float:
        return float(np.mean(self.scores))


def evaluate_policy(policy: Policy, domain: Domain, cfg: EvalConfig | None = None,
                    pool: PlantPool | None = None) -> EvalResult:
    """Run ``cfg.episodes`` episodes of ``policy`` in ``domain`` at once; score each with ``cfg.metric``. A robot
    domain's node comes from ``pool`` (kept running there), else is started for this call."""
    cfg = cfg or EvalConfig()
    size = domain.image_size

    def drive(images: Any, plant: Any) -> np.ndarray:
        if isinstance(images, np.ndarray) and images.shape[1:3] == (size[1], size[0]):
            return policy(images)
        return policy(fit_frames(np.stack([np.asarray(f) for f in images]), size))

    return _evaluate(lambda n: BatchPolicy(drive, n, "network"), domain, cfg, render=True, pool=pool)


def evaluate_expert(domain: Domain, cfg: EvalConfig | None = None, pool: PlantPool | None = None) -> EvalResult:
    """The privileged expert (pure pursuit on the true pose) on the same episodes: the teacher's own score."""
    cfg = cfg or EvalConfig()
    return _evaluate(lambda n: BatchPolicy(lambda images, plant: expert_actions(lane_rows(plant)), n, "expert",
                                           privileged=True), domain, cfg, render=False, pool=pool)


def _evaluate(make: Callable[[int], BatchPolicy], domain: Domain, cfg: EvalConfig, render: bool,
              pool: PlantPool | None) -> EvalResult:
    """The engine's rollout on a simulator of ``cfg.episodes`` robots, each with its own draw of θ — or, on a robot
    node, on its plant one episode after another."""
    seeds = [cfg.seed + e for e in range(cfg.episodes)]
    meta = {"domain": domain.name, "domain_kind": domain.kind}
    if domain.kind == "robot":
        with contextlib.ExitStack() as stack:
            plant = (pool or stack.enter_context(PlantPool())).robot(robot_spec(domain), cfg.map)
            trajs = [rollout(plant, make(1), [s], cfg.seconds, camera=render, metas=[meta])[0] for s in seeds]
    else:
        thetas = [domain.sample(np.random.default_rng(s)) for s in seeds]
        sim = Simulator(cfg.map, thetas, render=render)
        trajs = rollout(SimPlant(sim), make(sim.n), seeds, cfg.seconds, camera=render, metas=[meta] * sim.n)
    metric = METRICS[cfg.metric]
    return EvalResult([metric(t) for t in trajs], [t.termination for t in trajs])
