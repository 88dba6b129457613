"""Score a batched policy in a domain: all episodes side by side in one simulator, one network call per frame.

Each robot of the batch runs exactly the episode ``run_episode`` would run for the same seed (robots of
a ``Simulator`` batch are independent): it starts from the evaluation start distribution, sees a frame
every 1/frame_rate s, and stops when it leaves the road or hits an object of the map. Its physics-rate
trajectory is then scored by the same task metric code as every other run (by default the thesis' lane
score: episode time, −1 per second with one wheel out of the lane, −2 per second with both out).

``runner.episode.run_episodes`` batches physics and rendering too, but asks each agent for its command
one robot at a time; here one network call serves the whole batch.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from proxybench.domain.dynamics import TRACE_FIELDS
from proxybench.domain.simulator import Simulator
from proxybench.learning.collection import Policy
from proxybench.learning.domains import Domain
from proxybench.learning.expert import expert_actions
from proxybench.tasks.metrics import METRICS
from proxybench.tasks.trajectory import Trajectory

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


def _trajectory(sim: Simulator, i: int, trace: np.ndarray, frames: int, start: np.ndarray, seconds: float,
                termination: str, seed: int) -> Trajectory:
    rows = trace[:frames, i].reshape(-1, len(TRACE_FIELDS))
    p = sim.params[i]
    t = np.arange(rows.shape[0] + 1) * p.physics_dt
    poses = np.vstack([start[None], rows[:, :3]])
    meta = {"source": "simulation", "seed": seed, "episode_seconds": seconds}
    return Trajectory.from_poses(sim.map, t, poses, meta=meta, termination=termination,
                                 wheel_distance=p.wheel_distance)


def evaluate_policy(policy: Policy, domain: Domain, cfg: EvalConfig | None = None) -> EvalResult:
    """Run ``cfg.episodes`` episodes of ``policy`` in ``domain`` at once; score each with ``cfg.metric``."""
    return _evaluate(lambda sim, alive: policy(sim.render(active=alive)), domain, cfg or EvalConfig(), render=True)


def evaluate_expert(domain: Domain, cfg: EvalConfig | None = None) -> EvalResult:
    """The privileged expert (pure pursuit on the true pose) on the same episodes: the teacher's own score."""
    return _evaluate(lambda sim, alive: expert_actions(sim.lane), domain, cfg or EvalConfig(), render=False)


def _evaluate(command: Callable[[Simulator, np.ndarray], np.ndarray], domain: Domain, cfg: EvalConfig,
              render: bool) -> EvalResult:
    """The episode loop of ``runner.episode.run_episodes``, with one batched ``command(sim, alive)`` per frame."""
    seeds = [cfg.seed + e for e in range(cfg.episodes)]
    thetas = [domain.sample(np.random.default_rng(s)) for s in seeds]
    sim = Simulator(cfg.map, thetas, render=render)
    for i, s in enumerate(seeds):
        sim.reset(i, s)
    start = sim.state[:, :3].copy()
    steps = max(1, round(cfg.seconds / sim.frame_dt))
    trace = np.zeros((steps, sim.n, sim.substeps, len(TRACE_FIELDS)))
    frames = np.full(sim.n, steps)
    running = np.ones(sim.n, dtype=bool)
    ends = ["timeout"] * sim.n
    for k in range(steps):
        commands = np.asarray(command(sim, running), dtype=np.float64).reshape(sim.n, 2)
        sim.step(np.where(running[:, None], commands, 0.0), trace[k])
        for reason, hit in (("collision", sim.collided), ("off_road", sim.off_road)):
            for i in np.flatnonzero(running & hit):
                ends[i], frames[i], running[i] = reason, k + 1, False
        if not running.any():
            break
    metric = METRICS[cfg.metric]
    scores = [metric(_trajectory(sim, i, trace, int(frames[i]), start[i], cfg.seconds, ends[i], seeds[i]))
              for i in range(sim.n)]
    return EvalResult(scores, ends)
