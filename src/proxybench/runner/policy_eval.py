"""Score a batched policy: all episodes side by side in one simulator, one policy call per frame.

The episode engine (``runner.rollout``) on a :class:`~proxybench.runner.episode.SimPlant` with a batched policy
(:class:`~proxybench.runner.rollout.BatchPolicy`): each robot of the batch runs exactly the episode
``run_episode`` would run for the same seed: it starts from the evaluation start distribution, sees a frame
every 1/frame_rate s (the rendered pixels, no JPEG round trip), and stops when it leaves the road or hits an
object of the map. Its physics-rate trajectory is then scored by the same task metric code as every other run
(e.g. the thesis' lane score: episode time, −1 per second with one wheel out of the lane, −2 per second with
both out). On a robot node's plant the same engine plays the episodes one after another, from the starts those
seeds draw.

What the policy is (a network brought to its input size: :func:`frames_policy`; the BC expert) and which θ each
episode has is the caller's (``proxybench.learning.evaluation``).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from proxybench.domain.maps import Map
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator
from proxybench.runner.episode import SimPlant
from proxybench.runner.plants import fit_frames
from proxybench.runner.rollout import BatchPolicy, Plant, Policy, rollout
from proxybench.tasks.metrics import METRICS

__all__ = ["EvalResult", "frames_policy", "score_episodes"]


@dataclass
class EvalResult:
    """Per-episode scores and how each episode ended."""

    scores: list[float]
    terminations: list[str]

    @property
    def mean(self) -> float:
        return float(np.mean(self.scores))


def frames_policy(fn: Callable[[np.ndarray], np.ndarray], size: tuple[int, int], n: int,
                  name: str = "network") -> BatchPolicy:
    """A batched ``fn(frames (N, H, W, 3) uint8) -> wheel PWM (N, 2)`` as the engine's policy, the frames brought
    to its (width, height) ``size`` where the plant's differ (a robot's camera)."""
    def drive(images: Any, plant: Plant) -> np.ndarray:
        if isinstance(images, np.ndarray) and images.shape[1:3] == (size[1], size[0]):
            return fn(images)
        return fn(fit_frames(np.stack([np.asarray(f) for f in images]), size))

    return BatchPolicy(drive, n, name)


def score_episodes(make: Callable[[int], Policy], seeds: Sequence[int], seconds: float, metric: str, *,
                   map_: Map | str, thetas: Sequence[DomainParams] | None = None, plant: Plant | None = None,
                   render: bool = True, meta: dict[str, Any] | None = None) -> EvalResult:
    """Episode e of ``seconds`` from ``seeds[e]``, driven by ``make(n)`` (a policy of n robots), scored by the
    task metric ``metric``: on a simulator of ``map_`` whose robot e has θ ``thetas[e]``, all at once — or, given
    ``plant`` (a robot node's), on it one after another. ``render``: camera frames for the policy."""
    if plant is not None:
        trajs = [rollout(plant, make(1), [s], seconds, camera=render, metas=[meta])[0] for s in seeds]
    else:
        if thetas is None or len(thetas) != len(seeds):
            raise ValueError("a simulated evaluation needs one θ per seed")
        sim = Simulator(map_, list(thetas), render=render)
        trajs = rollout(SimPlant(sim), make(sim.n), seeds, seconds, camera=render, metas=[meta] * sim.n)
    score = METRICS[metric]
    return EvalResult([score(t) for t in trajs], [t.termination for t in trajs])
