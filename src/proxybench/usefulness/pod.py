"""POD, the naive usefulness measure: how different do the observations look?

The same open-loop command sequence is played from the same start in the proxy and in the target;
POD is the mean absolute difference of the two camera streams, per pixel and channel, in [0, 1]
(0: identical frames). It ignores what matters for a task, which is why the thesis argues for PRPV.

Both robots are one batch of the episode engine (``runner.rollout``: a two-robot simulator, robot 0 with
the proxy's θ, robot 1 with the target's, an open-loop policy), so the frames are rendered in one call
and the engine's ending rule applies: the mean runs over the frames before either robot's episode ended
(off the road, a collision), where the two camera streams still show comparable scenes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from proxybench.domain.maps import Map
from proxybench.domain.params import STRUCTURAL_FIELDS, DomainParams
from proxybench.domain.simulator import Simulator
from proxybench.runner.episode import SimPlant
from proxybench.runner.rollout import OpenLoopPolicy, rollout

__all__ = ["pod"]


def pod(
    proxy: DomainParams, target: DomainParams, m: Map | str, commands: np.ndarray, *,
    seed: int = 0, pose: tuple[float, float, float] | None = None,
) -> float:
    """Mean |frame_proxy − frame_target| / 255 over the frames of ``commands`` (T, 2) PWM, from one start.

    The target is seen at the proxy's image size and frame rate (the structural fields), so that frame k
    of one stream faces frame k of the other.
    """
    commands = np.asarray(commands, dtype=float).reshape(-1, 2)
    if not len(commands):
        return 0.0
    target = target.replace(**{f: getattr(proxy, f) for f in STRUCTURAL_FIELDS})
    sim = Simulator(m, [proxy, target])
    if pose is None:
        pose = sim.sample_start(np.random.default_rng(seed))
    diffs: list[float] = []

    def compare(k: int, images: Any, alive: np.ndarray, plant: SimPlant) -> None:
        if alive.all():
            diffs.append(float(np.abs(images[0].astype(np.int16) - images[1].astype(np.int16)).mean()) / 255.0)

    rollout(SimPlant(sim), OpenLoopPolicy(commands, 2), [seed, seed], len(commands) * sim.frame_dt,
            poses=[pose, pose], on_frame=compare)
    return sum(diffs) / len(diffs) if diffs else 0.0
