"""Lane-relative pose of a robot: which lane it is in, how far off its centre, how misaligned.

The lane is chosen among the segments of the tile under the robot as the one that best explains the
pose: the smallest ``|heading error| + |lateral| / (tile_size / 2)``. A robot driving the wrong way in
the left lane is therefore described by the lane it is heading along, with a large lateral offset
(it is out of lane), exactly as the AIDO metrics expect. The choice depends on the pose only, so a
recorded real trajectory gets the same lane pose as the simulator computed live.

The compiled kernel writes one row of ``LANE_POSE_FIELDS`` per pose; :func:`lane_pose` wraps it in a
dataclass for Python callers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from proxybench.domain.lanes import LaneArrays, LaneNetwork

__all__ = ["LANE_POSE_FIELDS", "LP", "LanePose", "lane_pose", "lane_poses", "lane_poses_on_segments"]

LANE_POSE_FIELDS = (
    "valid",  # 1 if the robot centre is on a drivable tile
    "segment",  # lane segment id, -1 if not valid
    "along",  # arc length along the segment [m]
    "lateral",  # offset from the right-lane centre [m], + = left
    "heading_error",  # robot heading minus lane heading [rad], + = turned left
    "left_in_lane",  # left wheel within lane_width/2 of the lane centre
    "right_in_lane",
    "left_on_road",  # left wheel on a drivable tile, inside the road's outer edge
    "right_on_road",
    "on_road",  # robot centre inside the road's outer edge
    "tile_i",
    "tile_j",
    "curvature",  # lane curvature at the robot [1/m], + = the lane turns left, 0 on straights
)


class LP:
    """Column indices into a lane-pose row."""

    VALID, SEGMENT, ALONG, LATERAL, HEADING_ERROR = 0, 1, 2, 3, 4
    LEFT_IN_LANE, RIGHT_IN_LANE, LEFT_ON_ROAD, RIGHT_ON_ROAD, ON_ROAD, TILE_I, TILE_J = 5, 6, 7, 8, 9, 10, 11
    CURVATURE = 12
    N = 13


@nb.njit(cache=True, inline="always")
def wrap_angle(a: float) -> float:
    """Angle wrapped to [-π, π)."""
    return a - 2.0 * math.pi * math.floor((a + math.pi) / (2.0 * math.pi))


@nb.njit(cache=True, inline="always")
def segment_local(k, x, y, seg_kind, seg_f):
    """(s, r, lane heading at s) of point (x, y) relative to segment k."""
    kind = seg_kind[k]
    x0 = seg_f[k, 0]
    y0 = seg_f[k, 1]
    h0 = seg_f[k, 2]
    if kind == 0:
        c = math.cos(h0)
        sn = math.sin(h0)
        dx = x - x0
        dy = y - y0
        return dx * c + dy * sn, -dx * sn + dy * c, h0
    sign = 1.0 if kind == 1 else -1.0
    cx = seg_f[k, 4]
    cy = seg_f[k, 5]
    radius = seg_f[k, 6]
    phi0 = seg_f[k, 7]
    rho = math.sqrt((x - cx) * (x - cx) + (y - cy) * (y - cy))
    dphi = wrap_angle(sign * (math.atan2(y - cy, x - cx) - phi0))
    s = radius * dphi
    return s, sign * (radius - rho), wrap_angle(h0 + dphi * sign)


@nb.njit(cache=True, inline="always")
def point_on_road(x, y, tile_kind, curve_corner, ts):
    """True if (x, y) is on a drivable tile and inside the road's outer edge."""
    i = int(math.floor(x / ts))
    j = int(math.floor(y / ts))
    if i < 0 or j < 0 or i >= tile_kind.shape[0] or j >= tile_kind.shape[1]:
        return False
    kind = tile_kind[i, j]
    if kind < 0:
        return False
    if kind == 1 or kind == 2:  # curves: the far corner lies outside the outer white line
        dx = x - curve_corner[i, j, 0]
        dy = y - curve_corner[i, j, 1]
        return dx * dx + dy * dy <= ts * ts
    return True


@nb.njit(cache=True)
def lane_pose_into(x, y, th, wheel_half, seg_kind, seg_f, tile_segs, tile_kind, curve_corner, ts, half_width, out):
    """Write the lane pose of robot pose (x, y, th) into ``out`` (length LP.N)."""
    for f in range(13):
        out[f] = 0.0
    out[1] = -1.0
    out[2] = math.nan
    out[3] = math.nan
    out[4] = math.nan
    i = int(math.floor(x / ts))
    j = int(math.floor(y / ts))
    out[10] = i
    out[11] = j
    # wheel contact points: half the wheel distance to each side of the axle centre
    sth = math.sin(th)
    cth = math.cos(th)
    lx = x - wheel_half * sth
    ly = y + wheel_half * cth
    rx = x + wheel_half * sth
    ry = y - wheel_half * cth
    out[7] = 1.0 if point_on_road(lx, ly, tile_kind, curve_corner, ts) else 0.0
    out[8] = 1.0 if point_on_road(rx, ry, tile_kind, curve_corner, ts) else 0.0
    out[9] = 1.0 if point_on_road(x, y, tile_kind, curve_corner, ts) else 0.0
    if i < 0 or j < 0 or i >= tile_kind.shape[0] or j >= tile_kind.shape[1] or tile_kind[i, j] < 0:
        return
    best = -1
    best_cost = 1e300
    best_s = 0.0
    best_r = 0.0
    best_h = 0.0
    inv_half_tile = 2.0 / ts
    for n in range(tile_segs.shape[2]):
        k = tile_segs[i, j, n]
        if k < 0:
            break
        s, r, lh = segment_local(k, x, y, seg_kind, seg_f)
        herr = wrap_angle(th - lh)
        cost = abs(herr) + abs(r) * inv_half_tile
        if cost < best_cost:
            best_cost = cost
            best = k
            best_s = s
            best_r = r
            best_h = herr
    if best < 0:
        return
    out[0] = 1.0
    out[1] = best
    out[2] = best_s
    out[3] = best_r
    out[4] = best_h
    _, rl, _ = segment_local(best, lx, ly, seg_kind, seg_f)
    _, rr, _ = segment_local(best, rx, ry, seg_kind, seg_f)
    out[5] = 1.0 if abs(rl) <= half_width else 0.0
    out[6] = 1.0 if abs(rr) <= half_width else 0.0
    kind = seg_kind[best]
    if kind != 0:
        out[12] = (1.0 if kind == 1 else -1.0) / seg_f[best, 6]


@nb.njit(cache=True)
def lane_poses_into(poses, wheel_half, seg_kind, seg_f, tile_segs, tile_kind, curve_corner, ts, half_width, out):
    for n in range(poses.shape[0]):
        lane_pose_into(
            poses[n, 0], poses[n, 1], poses[n, 2], wheel_half, seg_kind, seg_f, tile_segs, tile_kind,
            curve_corner, ts, half_width, out[n],
        )


@nb.njit(cache=True)
def lane_pose_on_segment_into(x, y, th, wheel_half, k, seg_kind, seg_f, tile_segs, tile_kind, curve_corner, ts,
                              half_width, out):
    """Like :func:`lane_pose_into`, but relative to segment ``k`` instead of the best-fitting one.

    Through an intersection the segments of one entry overlap, so the pose alone cannot say which lane
    the robot is in; a route names it (``proxybench.domain.routes``) and this measures against it.
    """
    lane_pose_into(x, y, th, wheel_half, seg_kind, seg_f, tile_segs, tile_kind, curve_corner, ts, half_width, out)
    if out[0] < 0.5 or k < 0:
        return
    s, r, lh = segment_local(k, x, y, seg_kind, seg_f)
    out[1] = k
    out[2] = s
    out[3] = r
    out[4] = wrap_angle(th - lh)
    sth = math.sin(th)
    cth = math.cos(th)
    _, rl, _ = segment_local(k, x - wheel_half * sth, y + wheel_half * cth, seg_kind, seg_f)
    _, rr, _ = segment_local(k, x + wheel_half * sth, y - wheel_half * cth, seg_kind, seg_f)
    out[5] = 1.0 if abs(rl) <= half_width else 0.0
    out[6] = 1.0 if abs(rr) <= half_width else 0.0
    kind = seg_kind[k]
    out[12] = 0.0 if kind == 0 else (1.0 if kind == 1 else -1.0) / seg_f[k, 6]


@nb.njit(cache=True)
def lane_poses_on_segments_into(poses, wheel_half, segs, seg_kind, seg_f, tile_segs, tile_kind, curve_corner, ts,
                                half_width, out):
    """Row n relative to segment ``segs[n]`` (best fit where it is -1); ``wheel_half`` (N,) per pose."""
    for n in range(poses.shape[0]):
        lane_pose_on_segment_into(
            poses[n, 0], poses[n, 1], poses[n, 2], wheel_half[n], segs[n], seg_kind, seg_f, tile_segs, tile_kind,
            curve_corner, ts, half_width, out[n],
        )


def _arrays(net: LaneNetwork | LaneArrays) -> LaneArrays:
    return net.arrays if isinstance(net, LaneNetwork) else net


def lane_poses(net: LaneNetwork | LaneArrays, poses: np.ndarray, wheel_distance: float = 0.102) -> np.ndarray:
    """Lane poses of many robot poses at once: (N, 3) [x, y, heading] → (N, LP.N) rows."""
    a = _arrays(net)
    poses = np.ascontiguousarray(poses, dtype=np.float64).reshape(-1, 3)
    out = np.empty((poses.shape[0], LP.N))
    lane_poses_into(
        poses, 0.5 * wheel_distance, a.seg_kind, a.seg_f, a.tile_segs, a.tile_kind, a.curve_corner,
        a.tile_size, a.lane_half_width, out,
    )
    return out


def lane_poses_on_segments(net: LaneNetwork | LaneArrays, poses: np.ndarray, segments: np.ndarray,
                           wheel_distance: float = 0.102) -> np.ndarray:
    """Lane poses (N, LP.N) of poses (N, 3) each measured against ``segments[n]`` (-1: the best fit)."""
    a = _arrays(net)
    poses = np.ascontiguousarray(poses, dtype=np.float64).reshape(-1, 3)
    segs = np.ascontiguousarray(segments, dtype=np.int64).reshape(-1)
    if segs.size != poses.shape[0]:
        raise ValueError(f"{segs.size} segments for {poses.shape[0]} poses")
    out = np.empty((poses.shape[0], LP.N))
    lane_poses_on_segments_into(
        poses, np.full(poses.shape[0], 0.5 * wheel_distance), segs, a.seg_kind, a.seg_f, a.tile_segs, a.tile_kind,
        a.curve_corner, a.tile_size, a.lane_half_width, out,
    )
    return out


@dataclass(frozen=True)
class LanePose:
    """Lane-relative pose of one robot; distances in metres, angles in radians."""

    valid: bool
    segment: int
    along: float
    lateral: float
    heading_error: float
    left_in_lane: bool
    right_in_lane: bool
    left_on_road: bool
    right_on_road: bool
    on_road: bool
    tile: tuple[int, int]
    curvature: float = 0.0

    @property
    def in_lane(self) -> bool:
        return self.left_in_lane and self.right_in_lane

    @staticmethod
    def from_row(row: np.ndarray) -> LanePose:
        r = row.tolist()  # Python floats: converting those is several times cheaper than NumPy scalars
        return LanePose(
            valid=bool(r[LP.VALID]),
            segment=int(r[LP.SEGMENT]),
            along=r[LP.ALONG],
            lateral=r[LP.LATERAL],
            heading_error=r[LP.HEADING_ERROR],
            left_in_lane=bool(r[LP.LEFT_IN_LANE]),
            right_in_lane=bool(r[LP.RIGHT_IN_LANE]),
            left_on_road=bool(r[LP.LEFT_ON_ROAD]),
            right_on_road=bool(r[LP.RIGHT_ON_ROAD]),
            on_road=bool(r[LP.ON_ROAD]),
            tile=(int(r[LP.TILE_I]), int(r[LP.TILE_J])),
            curvature=r[LP.CURVATURE],
        )

    def to_row(self) -> np.ndarray:
        """The inverse of :meth:`from_row`: a lane-pose row (LP.N,), e.g. for the vectorised expert."""
        row = np.zeros(LP.N)
        row[[LP.VALID, LP.SEGMENT, LP.ALONG, LP.LATERAL, LP.HEADING_ERROR, LP.LEFT_IN_LANE, LP.RIGHT_IN_LANE,
             LP.LEFT_ON_ROAD, LP.RIGHT_ON_ROAD, LP.ON_ROAD, LP.TILE_I, LP.TILE_J, LP.CURVATURE]] = (
            self.valid, self.segment, self.along, self.lateral, self.heading_error, self.left_in_lane,
            self.right_in_lane, self.left_on_road, self.right_on_road, self.on_road, *self.tile, self.curvature)
        return row


def lane_pose(net: LaneNetwork | LaneArrays, x: float, y: float, heading: float,
              wheel_distance: float = 0.102) -> LanePose:
    """Lane pose of one robot at (x, y) [m] with ``heading`` [rad].

    >>> from proxybench.domain.maps import load_map
    >>> net = LaneNetwork(load_map("straight_road"))
    >>> lp = lane_pose(net, 1.0, 0.585 * 1.5 - 0.22 * 0.585 + 0.03, 0.1)
    >>> round(lp.lateral, 6), round(lp.heading_error, 6), lp.in_lane
    (0.03, 0.1, True)
    """
    return LanePose.from_row(lane_poses(net, np.array([[x, y, heading]]), wheel_distance)[0])
