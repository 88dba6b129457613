"""What a robot node serves: the *backend* behind :class:`~proxybench.protocol.robot_node.RobotNode`.

The node speaks AIDO's simulator protocol (wire, language, ``episode_start`` payload, answers); a backend
is the world it speaks for: proxybench's own simulator (:mod:`proxybench.runner.sim_robot`), another
simulator (gym-duckietown, :mod:`proxybench.gym.backend`), or a physical robot's bridge. The node asks a
backend for very little, so that each of those is a small class:

- ``set_map(text)``: the map the caller sends (Duckietown YAML text); a map it cannot load is a
  ``ValueError`` naming the problem;
- ``reset(seed, pose, route, objects, camera)``: a new episode of its one robot at ``pose`` (map frame) with
  ``seed``; ``objects``: parked robots and duckies to place as obstacles;
- ``step_frame(pwm)``: one camera period with the wheel PWM held (the caller's ``step`` is whole frames),
  returning what happened in it (:class:`FrameStep`);
- ``camera()``, ``state()``, ``lane()``, ``route_choices()``, ``ending()``: what the robot sees and where it is;
- ``info()`` / ``description()``: what it is (kind, rates, parameters), for the caller and for people.

Units: metres, seconds, radians; poses in the map frame (duckietown-world's: x east, y north).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

from proxybench.domain.events import Event
from proxybench.domain.lane_pose import LanePose
from proxybench.domain.maps import MapObject
from proxybench.domain.routes import RouteInfo

__all__ = ["BackendState", "FrameStep", "RobotBackend"]

Pose = tuple[float, float, float]


@dataclass(frozen=True, slots=True)
class BackendState:
    """The robot now: ``pose`` (x [m], y [m], θ [rad]), body velocity ``v`` [m/s] and ``omega`` [rad/s],
    ``wheels``: left and right wheel angles [rad] (what its encoders count), and whether it is off the
    road or collided (the backend's own rule)."""

    pose: Pose
    v: float
    omega: float
    wheels: tuple[float, float]
    off_road: bool = False
    collided: bool = False


@dataclass(frozen=True, slots=True)
class FrameStep:
    """One camera period stepped: ``trace`` (n, 8) rows of t [s], x, y, θ, v, ω, pwm_left, pwm_right at the
    backend's physics rate (``robot_wire.TRACE_COLUMNS``); ``lanes``: the route's pinned and next lane
    before the step ((-1, -1) when the backend has no route tracker)."""

    trace: np.ndarray
    lanes: tuple[int, int] = (-1, -1)


class RobotBackend(Protocol):
    """The world behind a robot node (see the module docstring); one playable robot."""

    frame_dt: float  # [s] one camera period: the node's time advances in these
    encoder_resolution: float  # [rad] one encoder step

    def set_map(self, text: str) -> None: ...

    def reset(self, seed: int, pose: Pose | None, route: list[str] | None, objects: tuple[MapObject, ...],
              camera: bool = True) -> None:
        """A new episode; ``pose`` None: the backend draws one from ``seed``; ``camera``: frames will be asked
        for (a backend may render each frame as it steps, in the same exchange, when they will)."""

    def step_frame(self, pwm: np.ndarray) -> FrameStep: ...

    def time(self) -> float:
        """[s] since the episode started."""

    def camera(self) -> np.ndarray:
        """(H, W, 3) uint8 RGB frame for the current time."""

    def state(self) -> BackendState: ...

    def lane(self) -> tuple[LanePose, RouteInfo | None] | None:
        """The true lane pose and what a privileged agent is told of its route (None: no routes), or None
        where the backend knows no lane pose (privileged agents are then refused)."""

    def route_choices(self) -> dict[str, Any] | None:
        """``{"active": bool, "choices": [...]}`` of the route tracker (intersection turns), None: no routes."""

    def ending(self) -> Event | None:
        """Why the episode ended (an :class:`~proxybench.domain.events.Event`: ``kind`` a termination of
        ``robot_wire.TERMINATION_CODES``, ``with_`` what was hit), None while the robot drives on."""

    def info(self) -> dict[str, Any]:
        """``robot_interface_description.proxybench``: kind, frame_rate, physics_rate, wheel_distance,
        encoder_resolution, image_width, image_height, params (and anything else the backend reports)."""

    def description(self) -> str:
        """One paragraph for ``describe_node``: what this node is, plainly (simulated or real)."""

    def top_view(self, px_per_tile: int) -> np.ndarray:
        """(H, W, 3) uint8 top-down picture of the map with the robot (AIDO's ``get_ui_image``)."""
