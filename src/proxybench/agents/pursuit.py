"""Pure pursuit on the true lane geometry: the privileged expert (also the teacher for learning).

The robot aims at the point ``lookahead`` metres ahead along the lane centre and drives the circular
arc through it: ω = v · 2 y / (x² + y²) with (x, y) that point in the robot frame. The point is found
from the true lane pose (offset, heading error) and the lane's curvature at the robot, i.e. the lane
ahead is taken as an arc of constant curvature, which is exact within a tile.
"""

from __future__ import annotations

import math

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.agents.pid import wheels_for
from proxybench.agents.stopping import StopLineBrake, StopRule

__all__ = ["PurePursuitAgent", "lookahead_point"]


def lookahead_point(lateral: float, heading_error: float, curvature: float, distance: float) -> tuple[float, float]:
    """Robot-frame (x forward, y left) [m] of the lane-centre point ``distance`` [m] ahead of the robot's projection."""
    if abs(curvature) < 1e-9:
        tx, ty = distance, 0.0
    else:
        tx = math.sin(curvature * distance) / curvature
        ty = (1.0 - math.cos(curvature * distance)) / curvature
    dx, dy = tx, ty - lateral
    c, s = math.cos(heading_error), math.sin(heading_error)
    return c * dx + s * dy, -s * dx + c * dy


class PurePursuitAgent(Agent):
    """Follow the right-lane centre by pure pursuit at ``speed`` [m/s] with a ``lookahead`` [m].

    With a ``stop`` rule it also stops at the red lines before intersections (``agents.stopping``).
    """

    privileged = True
    name = "pure-pursuit"

    def __init__(self, speed: float = 0.35, lookahead: float = 0.25, stop: StopRule | None = None):
        if speed <= 0 or lookahead <= 0:
            raise ValueError(f"speed and lookahead must be positive, got {speed}, {lookahead}")
        self.speed, self.lookahead = speed, lookahead
        self._brake = StopLineBrake(stop) if stop is not None else None

    def reset(self, seed: int, episode: str | None = None) -> None:
        if self._brake is not None:
            self._brake.reset()

    def act(self, obs: Observation) -> np.ndarray:
        lp = self.true_lane_pose(obs)
        if not lp.valid:
            return np.zeros(2)
        x, y = lookahead_point(lp.lateral, lp.heading_error, lp.curvature, self.lookahead)
        kappa = 2.0 * y / max(x * x + y * y, 1e-6)
        speed = self.speed if self._brake is None else self._brake.speed(obs, self.speed)
        return wheels_for(speed, speed * kappa)
