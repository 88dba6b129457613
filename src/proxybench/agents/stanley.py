"""The Stanley lateral controller (Hoffmann et al. 2007, Stanford's DARPA Grand Challenge car), privileged.

Stanley steers a car-like vehicle by δ = ψ + atan(k e_f / (k_s + v)): the heading error plus a term that
turns towards the path in proportion to the cross-track error ``e_f`` of the *front axle*, flattened by the
speed. A Duckiebot has no steering wheel, so the agent treats itself as a bicycle with a virtual wheelbase
``wheelbase`` [m] (front "axle" that far ahead of the wheel axis) and turns δ into a turn rate by the bicycle
model ω = v tan δ / L, plus the lane's curvature as feed-forward (v κ). It reads the true lane pose and
inverts the *nominal* DB18 model for the PWM, as the other privileged agents do; it knows nothing of trim or
delay. Unlike PID, its correction saturates (atan, then ``max_steer``) and shrinks with speed.
"""

from __future__ import annotations

import math

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.agents.pid import wheels_for

__all__ = ["StanleyAgent"]


class StanleyAgent(Agent):
    """Stanley steering on the true lane pose at ``speed`` [m/s]; ``gain`` k [1/s], ``softening`` k_s [m/s],
    ``wheelbase`` L [m], ``max_steer`` [rad]."""

    privileged = True
    name = "stanley"

    def __init__(self, speed: float = 0.3, gain: float = 2.5, softening: float = 0.1, wheelbase: float = 0.1,
                 max_steer: float = 1.0):
        if speed <= 0 or gain <= 0 or softening <= 0 or wheelbase <= 0 or not 0 < max_steer < math.pi / 2:
            raise ValueError(f"need speed, gain, softening, wheelbase > 0 and 0 < max_steer < π/2; got speed="
                             f"{speed}, gain={gain}, softening={softening}, wheelbase={wheelbase}, "
                             f"max_steer={max_steer}")
        self.speed, self.gain, self.softening = speed, gain, softening
        self.wheelbase, self.max_steer = wheelbase, max_steer

    def steering(self, lateral: float, heading_error: float) -> float:
        """δ [rad] (+ = left) for an offset ``lateral`` [m] (+ = left) and ``heading_error`` [rad] (+ = left)."""
        front = lateral + self.wheelbase * math.sin(heading_error)  # cross-track error of the front axle
        delta = -heading_error - math.atan(self.gain * front / (self.softening + self.speed))
        return float(np.clip(delta, -self.max_steer, self.max_steer))

    def act(self, obs: Observation) -> np.ndarray:
        lp = self.true_lane_pose(obs)
        if not lp.valid:
            return np.zeros(2)
        delta = self.steering(lp.lateral, lp.heading_error)
        omega = self.speed * math.tan(delta) / self.wheelbase + self.speed * lp.curvature
        return wheels_for(self.speed, omega)
