"""Running agents in domains: episodes → trajectories."""

from proxybench.runner.episode import PrivilegedAgentError, run_episode

__all__ = ["PrivilegedAgentError", "run_episode"]
