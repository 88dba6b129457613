"""The agent contract shared by built-in agents and agents reached over the protocol.

An agent consumes observations and produces wheel commands; it never sees the simulator. A
*privileged* agent also reads the true lane pose, which only a simulator (or a motion-capture lab)
can provide; results of privileged agents say so.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from proxybench.domain.lane_pose import LanePose
from proxybench.domain.maps import Map
from proxybench.domain.routes import RouteInfo

__all__ = ["Agent", "Observation"]


@dataclass(frozen=True)
class Observation:
    """What a robot reports each frame (the AIDO ``observations`` message, plus privileged extras).

    ``camera``: (H, W, 3) uint8 RGB or None; ``time`` [s] since the episode start; ``odometry``: (left,
    right) wheel axis angles [rad], quantised to the encoder's ``odometry_resolution`` [rad];
    ``lane_pose``: ground truth, given to privileged agents only (through an intersection, measured
    against the lane of the chosen exit); ``route``: the turn chosen at the intersection ahead and the
    distance to its stop line, privileged agents only; ``pose``: the true (x [m], y [m], θ [rad]) in the
    map frame, privileged agents only; ``front_range``: the front time-of-flight sensor's range [m] (None:
    nothing in range, or a plant without one).
    """

    camera: np.ndarray | None
    time: float
    odometry: tuple[float, float] | None = None
    odometry_resolution: float | None = None
    lane_pose: LanePose | None = None
    route: RouteInfo | None = None
    pose: tuple[float, float, float] | None = None
    #: how to read the range sensor, when the plant has one: read on demand, since few agents use it and the
    #: beam cast would cost every frame of every episode
    range_reader: Callable[[], float | None] | None = field(default=None, repr=False, compare=False)

    @property
    def front_range(self) -> float | None:
        """The front time-of-flight range [m]; None when nothing is in range or the plant has no sensor."""
        return self.range_reader() if self.range_reader is not None else None


class Agent(ABC):
    """Observations → wheel PWM (left, right) in [-1, 1]."""

    #: needs ``Observation.lane_pose`` (ground truth), so it can only run where that is known
    privileged: bool = False
    #: short identifier used in result tables
    name: str = "agent"

    def set_map(self, map_: Map) -> None:  # noqa: B027 - optional hook
        """The map of the coming episode, before :meth:`reset` (an SDK agent serves it as the map layer)."""

    def reset(self, seed: int, episode: str | None = None) -> None:  # noqa: B027 - optional hook
        """Called at the start of every episode, before the first observation."""

    def true_lane_pose(self, obs: Observation) -> LanePose:
        """The privileged lane pose, or a clear error where the run did not provide it."""
        if obs.lane_pose is None:
            raise ValueError(f"{self.name} is privileged: the observation must carry the true lane_pose")
        return obs.lane_pose

    @abstractmethod
    def act(self, obs: Observation) -> np.ndarray:
        """Wheel PWM (left, right), shape (2,), each in [-1, 1]."""
