"""POD, the naive usefulness measure: how different do the observations look?

The same open-loop command sequence is played from the same start in the proxy and in the target
(:mod:`proxybench.experiments.predictivity.pod` asks the runner for the frames); POD is the mean absolute difference of
the two camera streams, per pixel and channel, in [0, 1] (0: identical frames), over the frames before
either robot's episode ended (where the two streams still show comparable scenes). It ignores what matters
for a task, which is why the thesis argues for PRPV.
"""

from __future__ import annotations

import numpy as np

__all__ = ["FrameDifference", "frame_difference"]


def frame_difference(a: np.ndarray, b: np.ndarray) -> float:
    """Mean |a − b| / 255 of two uint8 frames of one shape, in [0, 1]."""
    return float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean()) / 255.0


class FrameDifference:
    """POD accumulated over a stream of frame pairs: ``add(a, b)`` per frame, then ``value`` (0 without frames)."""

    def __init__(self) -> None:
        self.diffs: list[float] = []

    def add(self, a: np.ndarray, b: np.ndarray) -> None:
        self.diffs.append(frame_difference(a, b))

    @property
    def value(self) -> float:
        return sum(self.diffs) / len(self.diffs) if self.diffs else 0.0
