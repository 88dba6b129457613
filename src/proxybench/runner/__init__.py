"""Running agents in domains: episodes → trajectories."""

from proxybench.runner.episode import EpisodeRecord, PrivilegedAgentError, run_episode

__all__ = ["EpisodeRecord", "PrivilegedAgentError", "run_episode"]
