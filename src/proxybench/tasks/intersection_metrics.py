"""Intersection metrics: stopping at the red stop lines, and progress along the route.

Pure functions of a recorded trajectory: they read its lane pose and the route columns that
:class:`~proxybench.tasks.trajectory.Trajectory` computes from the map (``route_segment``,
``stop_distance``, ``on_route``), so simulated and real recorded runs are scored alike.

**Stopping at the line.** Duckietown's traffic code asks for a full stop at every red line before an
intersection; AIDO listed the rule but never implemented it, so the thresholds are proxybench's, chosen
from Duckietown practice:

- ``STOP_BAND`` = 0.30 m: the robot centre (wheel axle) must stop at most this far before the line,
  measured along its lane, and not past its near edge. dt-core's stop-line filter declares a robot "at
  the stop line" 0.22 m before it (``stop_distance``), and the body reaches ~0.1 m ahead of the axle.
- ``STOP_SPEED`` = 0.05 m/s: "stopped" is below a sixth of the 0.3 m/s cruise speed of the zoo agents.
- ``STOP_TIME`` = 0.5 s: the speed stays below ``STOP_SPEED`` that long without a break (a full stop,
  not a roll through).

An *entry* is the robot coming onto an intersection tile from a neighbouring tile, i.e. crossing a
stop line (every open edge of a 3-way or 4-way tile has one). It is *stopped* if the samples just
before it, while the robot was within ``STOP_BAND`` of that line, hold such a stop; otherwise it is a
violation. Speed is the displacement between samples over their time step, so recorded runs need no
velocity column.
"""

from __future__ import annotations

import numpy as np

from proxybench.domain.lane_pose import LP
from proxybench.tasks.progress import lane_steps
from proxybench.tasks.trajectory import Trajectory

__all__ = ["STOP_BAND", "STOP_SPEED", "STOP_TIME", "distance_along_route", "stop_line_entries",
           "stop_line_violations", "stopped_at_line"]

STOP_BAND = 0.30  # m before the stop line, along the lane
STOP_SPEED = 0.05  # m/s
STOP_TIME = 0.5  # s


def _speed(traj: Trajectory) -> np.ndarray:
    """Speed [m/s] over the interval ending at each sample (0 for the first)."""
    t = traj["t"]
    if len(t) < 2:
        return np.zeros(len(t))
    d = np.hypot(np.diff(traj["x"]), np.diff(traj["y"])) / np.diff(t)
    return np.r_[0.0, d]


def _stopped_before(traj: Trajectory, k: int, speed: np.ndarray) -> bool:
    """A full stop within the band before the line crossed at sample ``k``."""
    t, dist = traj["t"], traj["stop_distance"]
    j = k - 1
    while j >= 1 and 0.0 <= dist[j] <= STOP_BAND:  # NaN fails both: off any lane ending at a line
        j -= 1
    band = np.arange(j + 1, k)  # samples inside the band, the last one just before the line
    run_start = None
    for m in band:
        if speed[m] <= STOP_SPEED:
            run_start = m if run_start is None else run_start
            if t[m] - t[run_start - 1] >= STOP_TIME - 1e-9:
                return True
        else:
            run_start = None
    return False


def stop_line_entries(traj: Trajectory) -> tuple[int, int]:
    """(stop lines crossed, of those with a full stop before) over the episode."""
    if "route_segment" not in traj.columns or "stop_distance" not in traj.columns:
        return 0, 0
    rs = traj["route_segment"]
    lane = traj.lane
    ti, tj = lane[:, LP.TILE_I], lane[:, LP.TILE_J]
    valid = lane[:, LP.VALID] > 0.5
    entries = [k for k in range(1, len(rs))
               if rs[k] >= 0 and valid[k - 1] and (ti[k] != ti[k - 1] or tj[k] != tj[k - 1])]
    speed = _speed(traj)
    stopped = sum(_stopped_before(traj, k, speed) for k in entries)
    return len(entries), int(stopped)


def stop_line_violations(traj: Trajectory) -> float:
    """Stop lines crossed without a full stop within ``STOP_BAND`` before them (a count)."""
    entries, stopped = stop_line_entries(traj)
    return float(entries - stopped)


def stopped_at_line(traj: Trajectory) -> float:
    """Fraction of the stop lines crossed with a full stop before them; NaN if none was crossed."""
    entries, stopped = stop_line_entries(traj)
    return stopped / entries if entries else float("nan")


def distance_along_route(traj: Trajectory) -> float:
    """Progress along the route [m]: displacement projected on the lane direction while ``on_route``.

    Unlike ``driven_lanedir_consec`` it does not ask the robot to stay inside its lane; it asks it to
    stay on its route: after a wrong exit (a privileged agent told to turn left that drives straight on),
    or turned around, nothing counts until the robot is back on the route. NaN for trajectories without
    the route columns.
    """
    on = traj.columns.get("on_route")
    if on is None:
        return float("nan")
    return float(np.sum(np.where(on > 0.5, lane_steps(traj), 0.0)))
