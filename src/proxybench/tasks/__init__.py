"""Tasks: trajectories, metrics, scoring and benchmark files (knows nothing of how a run was made).

The names below load on first use (:mod:`proxybench.lazy`).
"""

from proxybench.lazy import lazy_exports

__getattr__ = lazy_exports(__name__, {n: "proxybench.tasks.trajectory" for n in ("Termination", "Trajectory",
                                                                                 "TrajectoryError")})

__all__ = ["Termination", "Trajectory", "TrajectoryError"]
