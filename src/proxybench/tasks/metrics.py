"""Task metrics: pure functions of a recorded trajectory, each with a unit and a direction.

The AIDO lane-following metrics as duckietown-world defines them, plus the thesis' lane score
(section 3.7.2) and the repeatability measures MPD / MOD (chapter 5). A metric never asks how the
trajectory was made, so simulated, reality-model and real recorded runs are scored alike.

>>> import numpy as np
>>> from proxybench.domain.maps import load_map
>>> m = load_map("straight_road")
>>> t = np.arange(0, 2.0 + 1e-9, 0.05)
>>> y = 0.585 * 1.5 - 0.22 * 0.585          # centre of the eastbound right lane
>>> traj = Trajectory.from_poses(m, t, np.stack([0.3 + 0.2 * t, np.full_like(t, y), 0 * t], axis=1))
>>> round(METRICS["driven_lanedir_consec"](traj), 6), round(METRICS["survival_time"](traj), 6)
(0.4, 2.0)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from proxybench.domain.lane_pose import LP
from proxybench.tasks.trajectory import Trajectory

__all__ = ["METRICS", "Metric", "lane_progress", "lane_steps", "repeatability"]

LANE_HALF_WIDTH = 0.5 * 0.376 * 0.585  # [m], Duckietown lane


@dataclass(frozen=True)
class Metric:
    """A named function trajectory → float; ``higher_is_better`` gives its direction."""

    name: str
    unit: str
    higher_is_better: bool
    description: str
    fn: Callable[[Trajectory], float]

    def __call__(self, traj: Trajectory) -> float:
        return float(self.fn(traj))

    @property
    def direction(self) -> str:
        return "↑" if self.higher_is_better else "↓"


def _dt(traj: Trajectory) -> np.ndarray:
    """Duration each sample stands for [s]: the interval that ends at it (0 for the first)."""
    t = traj["t"]
    return np.r_[0.0, np.diff(t)]


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


def _survival_time(traj: Trajectory) -> float:
    cap = traj.meta.get("episode_seconds")
    return min(traj.duration, float(cap)) if cap else traj.duration


def _driven_any(traj: Trajectory) -> float:
    return float(np.sum(np.hypot(np.diff(traj["x"]), np.diff(traj["y"]))))


def _deviation_center_line(traj: Trajectory) -> float:
    lane = traj.lane
    valid = lane[:, LP.VALID] > 0.5
    return float(np.sum(np.abs(np.where(valid, lane[:, LP.LATERAL], 0.0)) * _dt(traj)))


def _deviation_heading(traj: Trajectory) -> float:
    lane = traj.lane
    valid = lane[:, LP.VALID] > 0.5
    return float(np.sum(np.abs(np.where(valid, lane[:, LP.HEADING_ERROR], 0.0)) * _dt(traj)))


def _in_drivable_lane(traj: Trajectory) -> float:
    """Time [s] outside the lane the robot should drive in: no valid lane pose, or centre out of the lane."""
    lane = traj.lane
    valid = lane[:, LP.VALID] > 0.5
    inside = valid & (np.abs(np.nan_to_num(lane[:, LP.LATERAL], nan=1.0)) <= LANE_HALF_WIDTH)
    return float(np.sum((~inside) * _dt(traj)))


def _lane_score(traj: Trajectory) -> float:
    """Thesis §3.7.2: time, −1 per second with one wheel out of the lane, −2 per second with both out."""
    lane = traj.lane
    outs = (lane[:, LP.LEFT_IN_LANE] < 0.5).astype(int) + (lane[:, LP.RIGHT_IN_LANE] < 0.5).astype(int)
    return float(np.sum((1.0 - np.where(outs == 2, 2.0, outs)) * _dt(traj)))


def _metric_list() -> list[Metric]:
    from proxybench.tasks import intersection_metrics as im

    return [
        Metric("survival_time", "s", True, "time until the episode ended (capped at its length)", _survival_time),
        Metric("driven_lanedir_consec", "m", True, "progress along the lane direction, consecutive lanes only",
               lambda tr: float(np.sum(lane_progress(tr)))),
        Metric("driven_any", "m", True, "path length driven in any direction", _driven_any),
        Metric("deviation_center_line", "m·s", False, "∫ |lateral offset| dt", _deviation_center_line),
        Metric("deviation_heading", "rad·s", False, "∫ |heading error| dt", _deviation_heading),
        Metric("in_drivable_lane", "s", False, "time out of the right lane (wrong way and off-road count)",
               _in_drivable_lane),
        Metric("lane_score", "s", True, "thesis 3.7.2: time − 1/s one wheel out − 2/s both out", _lane_score),
        Metric("distance", "m", True, "thesis: distance along the lane (= driven_lanedir_consec)",
               lambda tr: float(np.sum(lane_progress(tr)))),
        Metric("distance_along_route", "m", True, "progress along the chosen route (wrong exits earn nothing)",
               im.distance_along_route),
        Metric("stop_line_violations", "count", False,
               f"stop lines crossed without a full stop (< {im.STOP_SPEED:g} m/s for {im.STOP_TIME:g} s "
               f"within {im.STOP_BAND:g} m before the line)", im.stop_line_violations),
        Metric("stopped_at_line", "fraction", True, "share of stop lines crossed after a full stop (NaN: none)",
               im.stopped_at_line),
    ]


#: every metric by name
METRICS: dict[str, Metric] = {m.name: m for m in _metric_list()}


def repeatability(runs: Sequence[Trajectory], grid_step: float = 0.02) -> dict[str, float]:
    """MPD [cm] and MOD [deg] over repeated runs of one route, with their standard deviations.

    Each run's lateral offset and heading error are resampled against the distance driven along the
    lane (a common grid every ``grid_step`` m up to the shortest run); at every grid point each run's
    deviation from the mean of all runs is taken. MPD / MOD are the means of the absolute deviations.
    """
    if len(runs) < 2:
        raise ValueError(f"repeatability needs at least 2 runs, got {len(runs)}")
    curves = []
    for tr in runs:
        s = np.cumsum(lane_progress(tr))
        lane = tr.lane
        keep = (lane[:, LP.VALID] > 0.5) & np.r_[True, np.diff(s) > 0]
        curves.append((s[keep], lane[keep, LP.LATERAL], lane[keep, LP.HEADING_ERROR]))
    s_max = min(c[0][-1] for c in curves if c[0].size) if all(c[0].size for c in curves) else 0.0
    if s_max <= grid_step:
        raise ValueError("the runs share no driven distance to compare")
    grid = np.arange(0.0, s_max, grid_step)
    lat = np.stack([np.interp(grid, s, la) for s, la, _ in curves])
    head = np.stack([np.interp(grid, s, he) for s, _, he in curves])
    dp = np.abs(lat - lat.mean(axis=0)) * 100.0
    do = np.degrees(np.abs(head - head.mean(axis=0)))
    return {"MPD_cm": float(dp.mean()), "MPD_std_cm": float(dp.std()),
            "MOD_deg": float(do.mean()), "MOD_std_deg": float(do.std())}
