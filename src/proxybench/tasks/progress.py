"""Progress along the lane: the per-sample displacement projected on the lane direction, and where a robot
enters an intersection. Shared by the lane metrics (:mod:`.metrics`) and the intersection metrics
(:mod:`.intersection_metrics`), which both read a recorded trajectory only.
"""

from __future__ import annotations

import numpy as np

from proxybench.domain.lane_pose import LP
from proxybench.tasks.trajectory import Trajectory

__all__ = ["LANE_HALF_WIDTH", "intersection_entries", "lane_progress", "lane_steps"]

LANE_HALF_WIDTH = 0.5 * 0.376 * 0.585  # [m], Duckietown lane


def lane_steps(traj: Trajectory) -> np.ndarray:
    """Per-sample displacement since the previous sample projected on the lane direction at it [m]."""
    lane = traj.lane
    x, y, th = traj["x"], traj["y"], traj["theta"]
    valid = lane[:, LP.VALID] > 0.5
    lane_heading = th - np.where(valid, lane[:, LP.HEADING_ERROR], 0.0)
    dx, dy = np.r_[0.0, np.diff(x)], np.r_[0.0, np.diff(y)]
    return dx * np.cos(lane_heading) + dy * np.sin(lane_heading)


def intersection_entries(traj: Trajectory) -> np.ndarray:
    """Per sample: the robot has just come onto an intersection tile (a new visit of its route).

    Read from the ``route_segment`` column (the pinned lane, -1 off intersections); all False for
    trajectories without it (files written before routes existed).
    """
    rs = traj.columns.get("route_segment")
    if rs is None:
        return np.zeros(len(traj), dtype=bool)
    return (rs >= 0) & np.r_[True, rs[1:] != rs[:-1]]


def lane_progress(traj: Trajectory) -> np.ndarray:
    """Per-sample progress along the lane direction [m], with duckietown-world's consecutive-lane rule.

    The displacement since the previous sample is projected on the lane direction at the sample. It
    counts only while the robot centre is inside the lane it is matched to, and the first lane segment
    the robot is matched to on a tile is *the* segment of that tile: progress made on any other
    segment of it counts zero. Driving the wrong way (in the left lane, or turned around in the right
    one) therefore earns nothing. The tie holds for the whole episode on maps without intersections,
    as in duckietown-world; with intersections it holds between them: every time the robot comes onto
    an intersection tile the ties are cleared, since a route may cross the same intersection by
    another lane, or drive a road again the other way.
    """
    lane = traj.lane
    valid = lane[:, LP.VALID] > 0.5
    inside = valid & (np.abs(np.nan_to_num(lane[:, LP.LATERAL], nan=1.0)) <= LANE_HALF_WIDTH)
    step = lane_steps(traj)
    tied: dict[tuple[int, int, int], int] = {}
    ok = np.zeros(len(traj), dtype=bool)
    seg = lane[:, LP.SEGMENT].astype(np.int64)
    ti, tj = lane[:, LP.TILE_I].astype(np.int64), lane[:, LP.TILE_J].astype(np.int64)
    stretch = np.cumsum(intersection_entries(traj))  # the stretch of road between intersections
    for k in np.flatnonzero(inside):
        key = (int(ti[k]), int(tj[k]), int(stretch[k]))
        ok[k] = tied.setdefault(key, int(seg[k])) == seg[k]
    return np.where(ok, step, 0.0)
