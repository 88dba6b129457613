"""Stopping at stop lines, for privileged agents: a speed schedule from the route's stop distance.

A privileged agent reads ``Observation.route`` (distance to the stop line ahead along its lane, whether
it is crossing an intersection) and scales its cruise speed with :class:`StopLineBrake`: slow down
approaching the line, stand still ``at`` metres before it for ``wait`` seconds, then drive through. The
defaults stop well inside the band the ``stop_line_violations`` metric checks (0–0.30 m before the line,
below 0.05 m/s for 0.5 s), with room for the benchmark's command latency.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from proxybench.agents.base import Observation

__all__ = ["StopLineBrake", "StopRule"]


@dataclass(frozen=True)
class StopRule:
    """Where and how long to stop: ``at`` [m] before the line, ``wait`` [s] standing, ``slow_from`` [m]
    before the line the approach starts, never slower than ``creep`` [m/s] until ``at`` is reached."""

    at: float = 0.12
    wait: float = 1.0
    slow_from: float = 0.30
    creep: float = 0.06

    def __post_init__(self) -> None:
        if not 0.0 <= self.at < self.slow_from:
            raise ValueError(f"need 0 <= at < slow_from, got at={self.at}, slow_from={self.slow_from}")
        if self.wait < 0 or self.creep <= 0:
            raise ValueError(f"wait must be >= 0 and creep > 0, got wait={self.wait}, creep={self.creep}")


class StopLineBrake:
    """The speed [m/s] to drive at, frame by frame; remembers whether the current line was served."""

    def __init__(self, rule: StopRule | None = None):
        self.rule = rule or StopRule()
        self.reset()

    def reset(self) -> None:
        self._stopped_at: float | None = None  # time [s] the stop began
        self._served = False  # stopped at the line ahead: drive through it

    def speed(self, obs: Observation, cruise: float) -> float:
        route, r = obs.route, self.rule
        if route is None:
            return cruise
        if route.in_intersection:  # past the line: the next one needs a new stop
            self._served, self._stopped_at = False, None
            return cruise
        d = route.stop_distance
        if self._served or not math.isfinite(d) or d > r.slow_from:
            return cruise
        if d > r.at and self._stopped_at is None:
            return max(r.creep, cruise * (d - r.at) / (r.slow_from - r.at))
        if self._stopped_at is None:
            self._stopped_at = obs.time
        if obs.time - self._stopped_at >= r.wait:
            self._served = True
            return cruise
        return 0.0
