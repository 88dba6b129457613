"""Tasks: trajectories, metrics, scoring and benchmark files (knows nothing of how a run was made)."""

from proxybench.tasks.trajectory import Trajectory, TrajectoryError

__all__ = ["Trajectory", "TrajectoryError"]
