"""Baseline agents with no perception worth the name: the bottom of the ranking, on purpose."""

from __future__ import annotations

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.agents.pid import wheels_for

__all__ = ["BangBangAgent", "RandomAgent", "StraightAgent"]


class RandomAgent(Agent):
    """Uniform random wheel commands, re-drawn every ``hold`` frames; seeded per episode."""

    name = "random"

    def __init__(self, low: float = -0.2, high: float = 1.0, hold: int = 3):
        if not -1.0 <= low <= high <= 1.0:
            raise ValueError(f"need -1 <= low <= high <= 1, got low={low}, high={high}")
        self.low, self.high, self.hold = low, high, max(1, hold)
        self._rng = np.random.default_rng(0)
        self._k = 0
        self._cmd = np.zeros(2)

    def reset(self, seed: int, episode: str | None = None) -> None:
        self._rng = np.random.default_rng(seed)
        self._k = 0

    def act(self, obs: Observation) -> np.ndarray:
        if self._k % self.hold == 0:
            self._cmd = self._rng.uniform(self.low, self.high, 2)
        self._k += 1
        return self._cmd.copy()


class StraightAgent(Agent):
    """Open loop: the same PWM on both wheels forever (what a robot does with no feedback at all)."""

    name = "straight"

    def __init__(self, pwm: float = 0.5):
        if not -1.0 <= pwm <= 1.0:
            raise ValueError(f"pwm must be in [-1, 1], got {pwm}")
        self.pwm = pwm

    def act(self, obs: Observation) -> np.ndarray:
        return np.array([self.pwm, self.pwm])


class BangBangAgent(Agent):
    """Privileged on/off steering: full turn towards the lane centre line whenever off it by > ``deadzone``."""

    privileged = True
    name = "bang-bang"

    def __init__(self, speed: float = 0.25, turn_rate: float = 2.5, deadzone: float = 0.02):
        self.speed, self.turn_rate, self.deadzone = speed, turn_rate, deadzone

    def act(self, obs: Observation) -> np.ndarray:
        lp = self.true_lane_pose(obs)
        if not lp.valid:
            return np.zeros(2)
        # signed error: + means the robot is (or is heading) left of the lane centre
        err = lp.lateral + 0.1 * lp.heading_error
        omega = 0.0 if abs(err) < self.deadzone else -np.sign(err) * self.turn_rate
        return wheels_for(self.speed, float(omega))
