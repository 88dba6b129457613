"""Repeatability studies (thesis ch. 5): how much do runs of one agent differ, and why?

Three settings, each N runs of the same agent from the same start pose, all *simulated* on the
reality model (a stand-in for real Duckiebots, see ``proxybench.domain.reality``):

- ``one robot``: the same robot N times; only latency jitter and sensor noise differ (episode seed);
- ``robots``: N robots, each with its own hardware deviation (trim, gain, camera mounting);
- ``labs``: N labs, each with its own light, road colour and surface texture.

MPD / MOD (``tasks.metrics.repeatability``) measure the spread of the lateral position and heading
along the route.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from proxybench.agents import make_agent
from proxybench.domain.params import DomainParams
from proxybench.domain.reality import hardware_variation, reality_params
from proxybench.domain.simulator import Simulator
from proxybench.runner.episode import run_episode
from proxybench.tasks.metrics import repeatability
from proxybench.tasks.trajectory import Trajectory

__all__ = ["SETTINGS", "RepeatabilityResult", "lab_variation", "repeatability_study"]

SETTINGS = ("one robot", "robots", "labs")


def lab_variation(rng: np.random.Generator, base: DomainParams) -> DomainParams:
    """Another lab: its own lights, road paint and floor texture."""
    light = tuple(float(v) for v in np.clip(rng.normal(1.0, 0.08, 3), 0.7, 1.3))
    road = tuple(float(v) for v in np.clip(np.asarray(base.road_rgb) + rng.normal(0.0, 8.0), 20, 120))
    return base.replace(light_rgb=light, road_rgb=road, brightness=float(rng.normal(0.0, 6.0)),
                        texture_seed=int(rng.integers(0, 2**31)), texture_noise=float(rng.uniform(0.05, 0.2)))


@dataclass
class RepeatabilityResult:
    """Per setting: the runs and their MPD / MOD figures."""

    runs: dict[str, list[Trajectory]]
    figures: dict[str, dict[str, float]]


def repeatability_study(
    agent: str, runs: int = 10, seconds: float = 30.0, map_name: str = "loop_3x3", seed: int = 0,
    image_size: tuple[int, int] = (160, 120), progress: Callable[[str, int], None] | None = None,
) -> RepeatabilityResult:
    """Run ``agent`` ``runs`` times in each setting; the start pose is the same for every run."""
    if runs < 2:
        raise ValueError(f"repeatability needs at least 2 runs per setting, got {runs}")
    w, h = image_size
    base = reality_params(image_width=w, image_height=h)
    start = Simulator(map_name, base, render=False).sample_start(np.random.default_rng(seed))
    rng = np.random.default_rng(seed + 1)
    params = {
        "one robot": [base] * runs,
        "robots": [hardware_variation(rng, base) for _ in range(runs)],
        "labs": [lab_variation(rng, base) for _ in range(runs)],
    }
    out: dict[str, list[Trajectory]] = {}
    figures: dict[str, dict[str, float]] = {}
    for setting in SETTINGS:
        trajs = []
        for k, p in enumerate(params[setting]):
            sim = Simulator(map_name, p)
            a = make_agent(agent)
            trajs.append(run_episode(sim, a, seed * 1000 + k, seconds, pose=start, camera=not a.privileged,
                                     meta={"setting": setting, "run": k, "source": "reality-model"}))
            if progress:
                progress(setting, k)
        out[setting] = trajs
        figures[setting] = repeatability(trajs)
    return RepeatabilityResult(out, figures)
