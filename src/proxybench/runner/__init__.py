"""Running agents in domains: episodes → trajectories."""

from proxybench.runner.episode import EpisodeRecord, run_episode

__all__ = ["EpisodeRecord", "run_episode"]
