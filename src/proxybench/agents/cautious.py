"""A cautious driver, privileged: speed scheduled by how hard the road and the robot's own error are.

Where the other controllers hold one cruise speed, this one chooses its speed every frame: full ``top_speed``
on a straight with the robot centred, less in curves (by the lane's curvature κ), less when off the centre or
misaligned, and a crawl when the front range sensor sees something within ``keep_clear`` metres. It steers by
the *bearing* of a point ``lookahead`` metres ahead on the lane centre (ω = k · bearing · v / lookahead, so the
turn scales with speed): a carrot-on-a-stick rule, not pure pursuit's arc. The PWM comes from the nominal DB18
model, as for the other privileged agents.
"""

from __future__ import annotations

import math

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.agents.pid import wheels_for

__all__ = ["CautiousAgent", "scheduled_speed"]


def scheduled_speed(top_speed: float, min_speed: float, curvature: float, lateral: float, heading_error: float,
                    caution: float) -> float:
    """Speed [m/s] for a lane pose: ``top_speed`` scaled down by curvature [1/m], offset [m] and heading error
    [rad], ``caution`` multiplying every penalty; never below ``min_speed``."""
    penalty = caution * (0.12 * abs(curvature) + 4.0 * abs(lateral) + 0.8 * abs(heading_error))
    return max(min_speed, top_speed * (1.0 - min(penalty, 1.0)))


class CautiousAgent(Agent):
    """Bearing steering with a scheduled speed in [``min_speed``, ``top_speed``] [m/s]; see the module docstring."""

    privileged = True
    name = "cautious"

    def __init__(self, top_speed: float = 0.3, min_speed: float = 0.08, caution: float = 1.0, lookahead: float = 0.2,
                 steer_gain: float = 2.0, keep_clear: float = 0.3):
        if not 0 < min_speed <= top_speed or caution < 0 or lookahead <= 0 or steer_gain <= 0:
            raise ValueError(f"need 0 < min_speed <= top_speed, caution >= 0, lookahead > 0, steer_gain > 0; got "
                             f"min_speed={min_speed}, top_speed={top_speed}, caution={caution}, "
                             f"lookahead={lookahead}, steer_gain={steer_gain}")
        self.top_speed, self.min_speed, self.caution = top_speed, min_speed, caution
        self.lookahead, self.steer_gain, self.keep_clear = lookahead, steer_gain, keep_clear

    def bearing(self, lateral: float, heading_error: float, curvature: float) -> float:
        """Angle [rad] (+ = left) from the robot's heading to the lane-centre point ``lookahead`` ahead."""
        d, k = self.lookahead, curvature
        # the lane centre ahead, in the lane frame at the robot's projection (x along, y left), as a circular arc
        ax, ay = (d, 0.0) if abs(k) < 1e-9 else (math.sin(k * d) / k, (1.0 - math.cos(k * d)) / k)
        return math.atan2(ay - lateral, ax) - heading_error

    def act(self, obs: Observation) -> np.ndarray:
        lp = self.true_lane_pose(obs)
        if not lp.valid:
            return np.zeros(2)
        v = scheduled_speed(self.top_speed, self.min_speed, lp.curvature, lp.lateral, lp.heading_error, self.caution)
        rng = obs.front_range
        if rng is not None and rng < self.keep_clear:
            v = self.min_speed * max(0.0, (rng - 0.1) / max(self.keep_clear - 0.1, 1e-6))
        if v <= 0.0:
            return np.zeros(2)  # stand still, do not spin
        omega = self.steer_gain * self.bearing(lp.lateral, lp.heading_error, lp.curvature) * v / self.lookahead
        return wheels_for(v, omega)
