"""POD of a proxy against a target whose θ is known: the open-loop replay (runner) and the measure (usefulness)."""

from __future__ import annotations

import numpy as np

from proxybench.domain.maps import Map
from proxybench.domain.params import STRUCTURAL_FIELDS, DomainParams
from proxybench.runner.replay import open_loop_frames
from proxybench.usefulness.pod import FrameDifference

__all__ = ["pod"]


def pod(
    proxy: DomainParams, target: DomainParams, m: Map | str, commands: np.ndarray, *,
    seed: int = 0, pose: tuple[float, float, float] | None = None,
) -> float:
    """Mean |frame_proxy − frame_target| / 255 over the frames of ``commands`` (T, 2) PWM, from one start.

    The target is seen at the proxy's image size and frame rate (the structural fields), so that frame k
    of one stream faces frame k of the other.
    """
    target = target.replace(**{f: getattr(proxy, f) for f in STRUCTURAL_FIELDS})
    acc = FrameDifference()
    open_loop_frames(m, [proxy, target], commands, lambda images: acc.add(images[0], images[1]), seed=seed, pose=pose)
    return acc.value
