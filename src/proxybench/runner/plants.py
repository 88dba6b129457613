"""Plants built from a domain spec: the batched simulator, or a robot node reached through the robot protocol.

Whoever drives a domain from outside a job (recording a drive, probing a node, collecting behaviour-cloning data,
evaluating a network on the target) gets its plant here, so that a robot node is started one way everywhere.
A :class:`PlantPool` keeps robot nodes running between uses (a PLV experiment collects and evaluates on the
target many times; starting a node costs seconds).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any

import numpy as np

from proxybench.domain.kinds import DomainKind
from proxybench.domain.maps import Map, load_map
from proxybench.domain.simulator import Simulator
from proxybench.runner.episode import SimPlant
from proxybench.runner.jobs import DomainSpec
from proxybench.runner.robot_episode import RobotPlant
from proxybench.runner.robots import open_robot

__all__ = ["PlantPool", "fit_frames", "open_plant"]


@contextlib.contextmanager
def open_plant(domain: DomainSpec, map_: Map | str, *, n: int = 1, frame_rate: float | None = None,
               npcs: Any = None, image_filter: Any = "camera") -> Iterator[SimPlant | RobotPlant]:
    """The plant of ``domain`` on ``map_``: a robot node started with its command (closed on exit; ``frame_rate``
    [Hz] is what it is asked to step at, default the domain's), or a simulator of ``n`` robots whose frames
    pass ``image_filter`` (default: the JPEG round trip camera agents see; None: raw renders)."""
    m = load_map(map_) if isinstance(map_, str) else map_
    if domain.kind is DomainKind.ROBOT:  # a node process or a DTPS robot: runner.robots knows both
        robot = open_robot(domain, frame_rate)
        try:
            yield robot.plant(m)
        finally:
            robot.close()
        return
    if isinstance(image_filter, str):
        from proxybench.runner.outcomes import camera_filter

        image_filter = camera_filter()
    yield SimPlant(Simulator(m, domain.params, n=n, npcs=npcs), image_filter)


class PlantPool:
    """Robot nodes started on first use and kept until :meth:`close` (or the end of a ``with`` block)."""

    def __init__(self) -> None:
        self._stack = contextlib.ExitStack()
        self._open: dict[tuple[str, str], Any] = {}

    def robot(self, domain: DomainSpec, map_name: str) -> RobotPlant:
        """The running node of ``domain`` (a robot domain) on ``map_name``, started now if it is not yet."""
        key = (domain.canonical(), map_name)
        if key not in self._open:
            self._open[key] = self._stack.enter_context(open_plant(domain, map_name))
        return self._open[key]

    def close(self) -> None:
        self._stack.close()
        self._open.clear()

    def __enter__(self) -> PlantPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def fit_frames(images: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Frames (N, H, W, 3) uint8 at (width, height) ``size``: area averages when shrinking, nearest pixels when
    growing (a robot's camera need not deliver the network's size).

    >>> fit_frames(np.arange(16, dtype=np.uint8).reshape(1, 4, 4, 1).repeat(3, -1), (2, 2))[0, :, :, 0]
    array([[ 2,  4],
           [10, 12]], dtype=uint8)
    """
    w, h = size
    x = np.asarray(images)
    if x.shape[1:3] == (h, w):
        return x
    return _axis(_axis(x.astype(np.float32), h, 1), w, 2).round().clip(0, 255).astype(np.uint8)


def _axis(x: np.ndarray, out: int, axis: int) -> np.ndarray:
    size = x.shape[axis]
    if out <= size:
        edges = np.linspace(0, size, out + 1).astype(int)
        shape = [1] * x.ndim
        shape[axis] = out
        return np.add.reduceat(x, edges[:-1], axis=axis) / np.diff(edges).reshape(shape)
    return np.take(x, (np.arange(out) * size // out), axis=axis)
