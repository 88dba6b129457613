"""A privileged lane-following controller: PID on the true lane pose.

It reads the ground-truth lateral offset and heading error (so it is an upper reference, not a
vision agent) and turns a (v, ω) demand into wheel PWM by inverting the steady state of the DB18
velocity model with *nominal* constants, as a real controller would: it does not know the domain's
trim, gain or delay.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.agents.stopping import StopLineBrake, StopRule

__all__ = ["LanePIDAgent", "PIDGains"]


@dataclass(frozen=True)
class PIDGains:
    """Gains on lateral offset [rad/s per m] and heading error [rad/s per rad]; integral on offset."""

    speed: float = 0.3  # forward speed demand [m/s]
    k_lateral: float = 10.0
    k_heading: float = 4.0
    k_integral: float = 2.0
    integral_limit: float = 0.3


class LanePIDAgent(Agent):
    """ω = −(k_lat e + k_head θ_e + k_i ∫e); PWM from (v, ω) by the nominal DB18 steady state.

    With a ``stop`` rule it also stops at the red lines before intersections (``agents.stopping``).
    """

    privileged = True
    name = "pid"

    def __init__(self, gains: PIDGains | None = None, frame_dt: float = 1 / 15, stop: StopRule | None = None):
        self.gains = gains or PIDGains()
        self.frame_dt = frame_dt
        self._integral = 0.0
        self._brake = StopLineBrake(stop) if stop is not None else None

    def reset(self, seed: int, episode: str | None = None) -> None:
        self._integral = 0.0
        if self._brake is not None:
            self._brake.reset()

    def act(self, obs: Observation) -> np.ndarray:
        lp = self.true_lane_pose(obs)
        g = self.gains
        if not lp.valid:
            return np.zeros(2)
        self._integral = float(np.clip(self._integral + lp.lateral * self.frame_dt, -g.integral_limit,
                                       g.integral_limit))
        omega = -(g.k_lateral * lp.lateral + g.k_heading * lp.heading_error + g.k_integral * self._integral)
        if self._brake is None:
            return wheels_for(g.speed, omega)
        speed = self._brake.speed(obs, g.speed)
        return wheels_for(speed, omega) if speed > 0 else np.zeros(2)  # stand still, do not spin


def wheels_for(v: float, omega: float, a_v: float = 5.0, b_v: float = 1.5, a_w: float = 4.0,
               b_w: float = 15.0) -> np.ndarray:
    """PWM (left, right) whose steady state under the nominal DB18 model is (v [m/s], ω [rad/s])."""
    total = v * a_v / b_v  # R + L
    diff = omega * a_w / b_w  # R - L
    return np.clip(np.array([0.5 * (total - diff), 0.5 * (total + diff)]), -1.0, 1.0)
