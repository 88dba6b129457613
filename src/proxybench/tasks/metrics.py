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
from proxybench.tasks.progress import LANE_HALF_WIDTH, lane_progress, lane_steps
from proxybench.tasks.trajectory import Trajectory

__all__ = ["METRICS", "UNIT_DECIMALS", "DeviationCurves", "Metric", "deviation_curves", "lane_progress", "lane_steps",
           "repeatability"]

#: decimals a value of each unit is shown with (tables, the web console): about the resolution a
#: Duckietown measurement has (1 cm, 0.1 s); a unit not listed gets 3
UNIT_DECIMALS = {"m": 2, "cm": 1, "s": 1, "m·s": 3, "rad": 3, "rad·s": 2, "deg": 1, "count": 0, "fraction": 2}


@dataclass(frozen=True)
class Metric:
    """A named function trajectory → float; ``higher_is_better`` gives its direction.

    ``unit`` is the unit of its value (``m``, ``s``, ``m·s``, …), ``label`` the name people read (tables,
    plots, the web console; default: the name in words), ``missing`` what a NaN value of it means (when
    it has a meaning of its own, e.g. "no stop line was crossed").

    >>> m = METRICS["deviation_center_line"]
    >>> m.title, m.direction, m.decimals
    ('Centre-line deviation [m·s]', '↓', 3)
    """

    name: str
    unit: str
    higher_is_better: bool
    description: str
    fn: Callable[[Trajectory], float]
    label: str = ""
    missing: str = ""

    def __call__(self, traj: Trajectory) -> float:
        return float(self.fn(traj))

    @property
    def direction(self) -> str:
        return "↑" if self.higher_is_better else "↓"

    @property
    def display_name(self) -> str:
        """``label``, or the name in words when it has none."""
        return self.label or self.name.replace("_", " ").capitalize()

    @property
    def title(self) -> str:
        """The label with its unit: ``Survival time [s]``."""
        return f"{self.display_name} [{self.unit}]" if self.unit else self.display_name

    @property
    def decimals(self) -> int:
        """Decimals its values are shown with (:data:`UNIT_DECIMALS`)."""
        return UNIT_DECIMALS.get(self.unit, 3)


def _dt(traj: Trajectory) -> np.ndarray:
    """Duration each sample stands for [s]: the interval that ends at it (0 for the first)."""
    t = traj["t"]
    return np.r_[0.0, np.diff(t)]


def _survival_time(traj: Trajectory) -> float:
    """Capped at the episode's length; a recording that ran to the end, sampled a frame or two inside it (a
    localised run's last pose at 9.67 s of 10 s), survived the whole episode (``meta["ran_whole_episode"]``)."""
    cap = traj.meta.get("episode_seconds")
    if cap and traj.meta.get("ran_whole_episode"):
        return float(cap)
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
        Metric("survival_time", "s", True, "time until the episode ended (capped at its length)", _survival_time,
               label="Survival time"),
        Metric("driven_lanedir_consec", "m", True, "progress along the lane direction, consecutive lanes only",
               lambda tr: float(np.sum(lane_progress(tr))), label="Distance along the lane"),
        Metric("driven_any", "m", True, "path length driven in any direction", _driven_any,
               label="Distance driven (any direction)"),
        Metric("deviation_center_line", "m·s", False, "∫ |lateral offset| dt", _deviation_center_line,
               label="Centre-line deviation"),
        Metric("deviation_heading", "rad·s", False, "∫ |heading error| dt", _deviation_heading,
               label="Heading deviation"),
        Metric("in_drivable_lane", "s", False, "time out of the right lane (wrong way and off-road count)",
               _in_drivable_lane, label="Time out of the lane"),
        Metric("lane_score", "s", True, "thesis 3.7.2: time − 1/s one wheel out − 2/s both out", _lane_score,
               label="Lane score"),
        Metric("distance", "m", True, "thesis: distance along the lane (= driven_lanedir_consec)",
               lambda tr: float(np.sum(lane_progress(tr))), label="Distance along the lane (thesis)"),
        Metric("distance_along_route", "m", True, "progress along the chosen route (wrong exits earn nothing)",
               im.distance_along_route, label="Distance along the route"),
        Metric("stop_line_violations", "count", False,
               f"stop lines crossed without a full stop (< {im.STOP_SPEED:g} m/s for {im.STOP_TIME:g} s "
               f"within {im.STOP_BAND:g} m before the line)", im.stop_line_violations, label="Stop-line violations"),
        Metric("stopped_at_line", "fraction", True, "share of stop lines crossed after a full stop (NaN: none)",
               im.stopped_at_line, label="Stopped at stop lines", missing="no stop line was crossed"),
    ]


#: every metric by name
METRICS: dict[str, Metric] = {m.name: m for m in _metric_list()}


@dataclass(frozen=True)
class DeviationCurves:
    """Every run's signed deviation from the lane centre against the distance driven along the lane.

    ``lateral_cm[k, j]``: run k's lateral offset from the centre of the right lane at distance ``s[j]``
    [cm], + = left of the centre; ``heading_deg[k, j]``: its heading minus the lane's [deg], + = turned
    left. NaN where run k did not get that far. The grid keeps the points at least two runs reached.
    """

    s: np.ndarray
    lateral_cm: np.ndarray
    heading_deg: np.ndarray

    @property
    def runs_at(self) -> np.ndarray:
        """How many runs reached each grid point."""
        return np.sum(np.isfinite(self.lateral_cm), axis=0)


def deviation_curves(runs: Sequence[Trajectory], grid_step: float = 0.02) -> DeviationCurves:
    """Resample each run's lateral offset and heading error on a common grid of lane distance (step [m])."""
    if len(runs) < 2:
        raise ValueError(f"repeatability needs at least 2 runs, got {len(runs)}")
    if grid_step <= 0:
        raise ValueError(f"grid_step must be > 0 m, got {grid_step}")
    curves = []
    for tr in runs:
        s = np.cumsum(lane_progress(tr))
        lane = tr.lane
        keep = (lane[:, LP.VALID] > 0.5) & np.r_[True, np.diff(s) > 0]
        curves.append((s[keep], lane[keep, LP.LATERAL], lane[keep, LP.HEADING_ERROR]))
    reach = sorted((c[0][-1] if c[0].size else 0.0 for c in curves), reverse=True)
    if reach[1] <= grid_step:
        raise ValueError("the runs share no driven distance to compare (fewer than 2 runs drove along the lane)")
    grid = np.arange(0.0, reach[1], grid_step)

    def resample(s: np.ndarray, v: np.ndarray) -> np.ndarray:
        out = np.interp(grid, s, v) if s.size else np.full(grid.size, np.nan)
        out[(grid > (s[-1] if s.size else -1.0)) | (grid < (s[0] if s.size else 0.0))] = np.nan
        return out

    lat = np.stack([resample(s, la) for s, la, _ in curves]) * 100.0
    head = np.degrees(np.stack([resample(s, he) for s, _, he in curves]))
    return DeviationCurves(grid, lat, head)


def _pooled_std(values: np.ndarray) -> float:
    """Across-run standard deviation at each grid point (ddof 1), pooled along the route (root mean variance)."""
    ok = np.sum(np.isfinite(values), axis=0) >= 2
    return float(np.sqrt(np.mean(np.nanvar(values[:, ok], axis=0, ddof=1))))


def _components(values: np.ndarray, groups: Sequence[str]) -> tuple[float, float]:
    """Within-group and between-group standard deviations, on grid points every run reached.

    Within: runs around their own group's mean curve (variance pooled over groups by degrees of
    freedom, then along the route); between: the group mean curves around each other (ddof 1).
    """
    labels = np.asarray(groups)
    names = list(dict.fromkeys(groups))
    means = np.stack([values[labels == g].mean(axis=0) for g in names])
    df = sum(int(np.sum(labels == g)) - 1 for g in names)
    ss = sum(np.sum((values[labels == g] - means[k]) ** 2, axis=0) for k, g in enumerate(names))
    within = float(np.sqrt(np.mean(ss / df))) if df > 0 else float("nan")
    between = float(np.sqrt(np.mean(np.var(means, axis=0, ddof=1)))) if len(names) >= 2 else float("nan")
    return within, between


def repeatability(runs: Sequence[Trajectory], grid_step: float = 0.02,
                  groups: Sequence[str] | None = None) -> dict[str, float]:
    """MPD [cm] and MOD [deg] of repeated runs of one route, as thesis §5.4 defines them.

    "MPD at a point along a trajectory is computed as the mean lateral displacement of the Duckiebot
    from the center of the lane. Similarly, MOD represents the mean orientation with respect to the
    lane orientation. For each set of experiments, we compute the average and the standard deviation
    along the trajectory itself." So, on a grid of distance along the lane:

    - ``MPD_cm`` = the route average of MPD(s) = mean over runs of the *signed* lateral offset at s
      (+ = left of the right lane's centre); ``MOD_deg`` likewise for the heading error. A robot that
      keeps 6 cm right of the centre has MPD −6 cm, however repeatable it is (the thesis' 1×9 run: −6.2).
    - ``MPD_std_cm`` / ``MOD_std_deg`` = the standard deviation across runs at each point, pooled along
      the route: the run-to-run variability the thesis reads from it ("low variability ... on the same
      hardware"). The other reading of its sentence, the spread of MPD(s) along the route, is
      ``MPD_std_route_cm`` / ``MOD_std_route_deg``.
    - With ``groups`` (one label per run: its robot, or lab), ``*_within_std`` is the spread of runs
      around their own group's mean curve and ``*_between_std`` that of the group means: how much of
      the variability is the robot (or lab) and how much the run (on the stretch every run reached).

    >>> import numpy as np
    >>> from proxybench.domain.maps import load_map
    >>> road, t = load_map("straight_road"), np.arange(0, 5.0 + 1e-9, 0.05)
    >>> y = 0.585 * 1.5 - 0.22 * 0.585                   # centre of the eastbound right lane
    >>> runs = [Trajectory.from_poses(road, t, np.stack([0.3 + 0.2 * t, np.full_like(t, y + d), 0 * t], axis=1))
    ...         for d in (0.01, 0.03)]                     # 1 cm and 3 cm left of the centre
    >>> f = repeatability(runs)
    >>> round(f["MPD_cm"], 6), round(f["MPD_std_cm"], 6), round(f["MOD_deg"], 6)
    (2.0, 1.414214, 0.0)
    """
    c = deviation_curves(runs, grid_step)
    ok = c.runs_at >= 2
    mpd_s, mod_s = np.nanmean(c.lateral_cm[:, ok], axis=0), np.nanmean(c.heading_deg[:, ok], axis=0)
    out = {"MPD_cm": float(mpd_s.mean()), "MPD_std_cm": _pooled_std(c.lateral_cm),
           "MOD_deg": float(mod_s.mean()), "MOD_std_deg": _pooled_std(c.heading_deg),
           "MPD_std_route_cm": float(mpd_s.std()), "MOD_std_route_deg": float(mod_s.std()),
           "route_m": float(c.s[ok][-1] + grid_step) if ok.any() else 0.0, "runs": float(len(runs))}
    if groups is not None:
        if len(groups) != len(runs):
            raise ValueError(f"groups: one label per run, got {len(groups)} labels for {len(runs)} runs")
        full = c.runs_at == len(runs)
        if not full.any():
            raise ValueError("no stretch of the route was reached by every run: cannot split the variability")
        out["MPD_within_std_cm"], out["MPD_between_std_cm"] = _components(c.lateral_cm[:, full], groups)
        out["MOD_within_std_deg"], out["MOD_between_std_deg"] = _components(c.heading_deg[:, full], groups)
    return out
