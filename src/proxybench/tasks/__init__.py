"""Tasks: trajectories, metrics, scoring and benchmark files (knows nothing of how a run was made)."""

from proxybench.tasks.trajectory import Termination, Trajectory, TrajectoryError

__all__ = ["Termination", "Trajectory", "TrajectoryError"]
