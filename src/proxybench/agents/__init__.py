"""Built-in agents: observation (+ own state) → wheel commands."""

from proxybench.agents.base import Agent, Observation
from proxybench.agents.pid import LanePIDAgent
from proxybench.agents.zoo import ZOO, agent_names, make_agent

__all__ = ["ZOO", "Agent", "LanePIDAgent", "Observation", "agent_names", "make_agent"]
