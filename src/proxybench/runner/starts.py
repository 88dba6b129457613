"""Start poses made explicit: the pose each episode seed draws from a map's start distribution.

Targets and proxies replay one another's episodes from the same starts (paired episodes), so a live target
writes down the start each seed draws before any episode runs.
"""

from __future__ import annotations

import numpy as np

from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator

__all__ = ["start_pose", "start_poses"]


def start_poses(map_name: str, seeds: list[int],
                params: DomainParams | None = None) -> list[tuple[float, float, float]]:
    """The start pose (x [m], y [m], θ [rad]) each seed draws (the simulator's start distribution)."""
    sim = Simulator(map_name, params, render=False)
    return [tuple(float(v) for v in sim.sample_start(np.random.default_rng(s))) for s in seeds]


def start_pose(map_name: str, seed: int, params: DomainParams | None = None) -> tuple[float, float, float]:
    """The start pose one seed draws."""
    return start_poses(map_name, [seed], params)[0]
