"""POD, the naive usefulness measure: how different do the observations look?

The same open-loop command sequence is played from the same start in the proxy and in the target;
POD is the mean absolute difference of the two camera streams, per pixel and channel, in [0, 1]
(0: identical frames). It ignores what matters for a task, which is why the thesis argues for PRPV.
"""

from __future__ import annotations

import numpy as np

from proxybench.domain.maps import Map
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator

__all__ = ["pod"]


def pod(
    proxy: DomainParams, target: DomainParams, m: Map | str, commands: np.ndarray, *,
    seed: int = 0, pose: tuple[float, float, float] | None = None,
) -> float:
    """Mean |frame_proxy − frame_target| / 255 over the frames of ``commands`` (T, 2) PWM, from one start."""
    commands = np.asarray(commands, dtype=float).reshape(-1, 2)
    if (proxy.image_width, proxy.image_height) != (target.image_width, target.image_height):
        target = target.replace(image_width=proxy.image_width, image_height=proxy.image_height)
    sims = [Simulator(m, p) for p in (proxy, target)]
    if pose is None:
        pose = sims[1].sample_start(np.random.default_rng(seed))
    for s in sims:
        s.reset(0, seed, pose)
    total = 0.0
    for u in commands:
        frames = [s.render()[0].astype(np.int16) for s in sims]
        total += float(np.abs(frames[0] - frames[1]).mean()) / 255.0
        for s in sims:
            s.step(u[None])
    return total / max(len(commands), 1)
