"""The front time-of-flight range sensor of a DB21: distance to the first object straight ahead.

A single beam from ``TOF_FORWARD`` ahead of the axle centre along the heading, against the footprints of the
map's colliding objects (circles and rectangles, ``objects.pack_objects``) and other robots (circles of
``ROBOT_RADIUS``). Nothing within ``TOF_MAX_RANGE`` gives None, as the DB21's driver reports out of range.
Extra duckies and pedestrians of a world are not seen (they are drawn, not packed as colliders here). The
beam is a line, not a cone: a real sensor's field of view (~27°) sees a little more at the sides.

>>> import numpy as np
>>> col = np.array([[1.0, 0.0, 1.0, 0.0, 0.05, 0.0, 0.1]])   # a circle of radius 5 cm at (1, 0)
>>> round(front_range(col, np.zeros((0, 3)), 0.0, 0.0, 0.0), 3)
0.85
>>> front_range(col, np.zeros((0, 3)), 0.0, 0.0, np.pi) is None
True
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

__all__ = ["ROBOT_RADIUS", "TOF_FORWARD", "TOF_MAX_RANGE", "front_range"]

TOF_FORWARD = 0.10  # [m] sensor ahead of the axle centre
TOF_MAX_RANGE = 1.2  # [m] beyond this: out of range
ROBOT_RADIUS = 0.08  # [m] another robot (or a robot-like object) seen as a circle


@nb.njit(cache=True)
def _circle(ox, oy, dx, dy, cx, cy, r):
    fx, fy = ox - cx, oy - cy
    b = fx * dx + fy * dy
    c = fx * fx + fy * fy - r * r
    disc = b * b - c
    if disc < 0.0:
        return math.inf
    s = -b - math.sqrt(disc)
    if s >= 0.0:
        return s
    return 0.0 if c <= 0.0 else math.inf  # inside it: touching


@nb.njit(cache=True)
def _box(ox, oy, dx, dy, cx, cy, cs, sn, a, b):
    # the ray in the box frame, then the slab method
    px = cs * (ox - cx) + sn * (oy - cy)
    py = -sn * (ox - cx) + cs * (oy - cy)
    vx = cs * dx + sn * dy
    vy = -sn * dx + cs * dy
    lo, hi = 0.0, math.inf
    for p, v, h in ((px, vx, a), (py, vy, b)):
        if abs(v) < 1e-12:
            if abs(p) > h:
                return math.inf
        else:
            t1, t2 = (-h - p) / v, (h - p) / v
            lo, hi = max(lo, min(t1, t2)), min(hi, max(t1, t2))
    return lo if lo <= hi else math.inf


@nb.njit(cache=True)
def _cast(colliders, robots, ox, oy, dx, dy):
    best = math.inf
    for m in range(colliders.shape[0]):
        c = colliders[m]
        if c[5] > 0.0:
            s = _box(ox, oy, dx, dy, c[0], c[1], c[2], c[3], c[4], c[5])
        else:
            s = _circle(ox, oy, dx, dy, c[0], c[1], c[4] if c[4] > 0.0 else ROBOT_RADIUS)
        best = min(best, s)
    for k in range(robots.shape[0]):
        best = min(best, _circle(ox, oy, dx, dy, robots[k, 0], robots[k, 1], ROBOT_RADIUS))
    return best


def front_range(colliders: np.ndarray, robots: np.ndarray, x: float, y: float, theta: float,
                max_range: float = TOF_MAX_RANGE) -> float | None:
    """Range [m] from the sensor of a robot at (x, y, θ) to the first collider or robot (M, ≥2) ahead; None
    beyond ``max_range``."""
    dx, dy = math.cos(theta), math.sin(theta)
    s = _cast(colliders, robots, x + TOF_FORWARD * dx, y + TOF_FORWARD * dy, dx, dy)
    return float(s) if s <= max_range else None
