"""Built-in agents: observation (+ own state) → wheel commands."""

from proxybench.agents.base import Agent, Observation
from proxybench.agents.pid import LanePIDAgent

__all__ = ["Agent", "LanePIDAgent", "Observation"]
