"""Lane geometry: the right-lane centre curves of every drivable tile, as exact lines and arcs.

Each lane segment crosses one tile from an entry edge to an exit edge (straight on, or a quarter-circle
turn); through intersections there is one segment per allowed (entry, exit) pair. Like highway-env's
lanes, a segment is reached through four methods, everything else is written once on top:

- ``position(s, r)``: map-frame point at arc length ``s`` [m] and lateral offset ``r`` [m, + = left];
- ``local_coordinates(x, y)``: the inverse, ``(s, r)``;
- ``heading_at(s)``: lane direction [rad];
- ``width_at(s)``: lane width [m].

>>> from proxybench.domain.maps import load_map
>>> net = LaneNetwork(load_map("loop_3x3"))
>>> len(net.segments)
16
>>> seg = net.segments[0]
>>> s, r = seg.local_coordinates(*seg.position(0.1, 0.02))
>>> round(s, 9), round(r, 9)
(0.1, 0.02)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from proxybench.domain.maps import DRIVABLE_KINDS, GROUND_KINDS, Direction, Map

__all__ = ["ROAD", "LaneNetwork", "LaneSegment", "RoadGeometry", "SegmentKind"]


@dataclass(frozen=True)
class RoadGeometry:
    """Duckietown road markings in tile units (fractions of ``tile_size``), measured from the road centre.

    ``lane_offset`` is where the right-lane centre lies; a wheel is "in the lane" while it is within
    ``lane_width / 2`` of it. The same numbers draw the textures, so what the camera sees and what the
    lane pose says agree.
    """

    lane_offset: float = 0.22
    lane_width: float = 0.376
    yellow_half_width: float = 0.0215  # 2.5 cm dashed centre line
    white_inner: float = 0.408  # white outer line spans [white_inner, white_outer] from the road centre
    white_outer: float = 0.49
    dash_length: float = 1.0 / 12.0  # yellow dash and gap, so a straight tile holds six dashes
    stop_line_depth: float = 0.085  # 5 cm red stop lines at intersection entries


ROAD = RoadGeometry()


class SegmentKind:
    STRAIGHT = 0
    LEFT = 1
    RIGHT = 2
    NAMES = ("straight", "left", "right")


def _wrap(angle: float) -> float:
    """Angle wrapped to [-π, π)."""
    return angle - 2.0 * math.pi * math.floor((angle + math.pi) / (2.0 * math.pi))


@dataclass(frozen=True)
class LaneSegment:
    """One right-lane centre curve across one tile. Lengths in metres, angles in radians."""

    index: int
    tile: tuple[int, int]
    entry: Direction  # edge the lane enters through
    exit: Direction  # edge the lane leaves through
    kind: int  # SegmentKind
    x0: float  # start point and heading
    y0: float
    heading0: float
    length: float
    cx: float = 0.0  # arc centre and radius (turns only)
    cy: float = 0.0
    radius: float = 0.0
    width: float = 0.0

    @property
    def kind_name(self) -> str:
        return SegmentKind.NAMES[self.kind]

    @property
    def _phi0(self) -> float:
        return math.atan2(self.y0 - self.cy, self.x0 - self.cx)

    def position(self, s: float, r: float = 0.0) -> tuple[float, float]:
        """Map-frame point ``s`` [m] along the lane and ``r`` [m] to its left."""
        if self.kind == SegmentKind.STRAIGHT:
            c, sn = math.cos(self.heading0), math.sin(self.heading0)
            return (self.x0 + s * c - r * sn, self.y0 + s * sn + r * c)
        sign = 1.0 if self.kind == SegmentKind.LEFT else -1.0
        phi = self._phi0 + sign * s / self.radius
        rho = self.radius - sign * r
        return (self.cx + rho * math.cos(phi), self.cy + rho * math.sin(phi))

    def local_coordinates(self, x: float, y: float) -> tuple[float, float]:
        """``(s, r)`` of a map-frame point: arc length along the lane and signed offset (+ = left)."""
        if self.kind == SegmentKind.STRAIGHT:
            c, sn = math.cos(self.heading0), math.sin(self.heading0)
            dx, dy = x - self.x0, y - self.y0
            return (dx * c + dy * sn, -dx * sn + dy * c)
        sign = 1.0 if self.kind == SegmentKind.LEFT else -1.0
        rho = math.hypot(x - self.cx, y - self.cy)
        phi = math.atan2(y - self.cy, x - self.cx)
        s = self.radius * _wrap(sign * (phi - self._phi0))
        return (s, sign * (self.radius - rho))

    def heading_at(self, s: float) -> float:
        """Lane direction [rad] at arc length ``s``."""
        if self.kind == SegmentKind.STRAIGHT:
            return self.heading0
        sign = 1.0 if self.kind == SegmentKind.LEFT else -1.0
        return _wrap(self.heading0 + sign * s / self.radius)

    def width_at(self, s: float) -> float:
        """Lane width [m]; constant on Duckietown roads."""
        return self.width

    def sample(self, n: int = 16) -> np.ndarray:
        """``n`` points along the centre line, shape (n, 2), for drawing."""
        return np.array([self.position(s) for s in np.linspace(0.0, self.length, n)])


def _segment_between(
    index: int, i: int, j: int, ts: float, entry: Direction, exit_: Direction, geo: RoadGeometry
) -> LaneSegment:
    """The right-lane curve entering tile (i, j) through ``entry`` and leaving through ``exit_``."""
    cx_t, cy_t = (i + 0.5) * ts, (j + 0.5) * ts
    h_in = entry.opposite  # heading when entering
    ex, ey = entry.unit
    rx, ry = h_in.rotated(3).unit  # right of the entry heading
    x0 = cx_t + 0.5 * ts * ex + geo.lane_offset * ts * rx
    y0 = cy_t + 0.5 * ts * ey + geo.lane_offset * ts * ry
    heading0 = math.pi / 2 * int(h_in)
    turn = (int(exit_) - int(h_in)) % 4
    width = geo.lane_width * ts
    if turn == 0:
        return LaneSegment(index, (i, j), entry, exit_, SegmentKind.STRAIGHT, x0, y0, heading0, ts, width=width)
    if turn not in (1, 3):
        raise ValueError("a lane cannot leave through the edge it entered")
    ox, oy = exit_.unit
    corner_x = cx_t + 0.5 * ts * (ex + ox)
    corner_y = cy_t + 0.5 * ts * (ey + oy)
    if turn == 1:
        kind, radius = SegmentKind.LEFT, (0.5 + geo.lane_offset) * ts
    else:
        kind, radius = SegmentKind.RIGHT, (0.5 - geo.lane_offset) * ts
    return LaneSegment(
        index, (i, j), entry, exit_, kind, x0, y0, heading0, radius * math.pi / 2, corner_x, corner_y, radius, width
    )


class LaneNetwork:
    """All lane segments of a map, their connections, and flat arrays for the compiled kernels."""

    MAX_SEGMENTS_PER_TILE = 12  # a 4-way tile: 4 entries × 3 exits

    def __init__(self, map_: Map, geometry: RoadGeometry = ROAD):
        self.map = map_
        self.geometry = geometry
        segments: list[LaneSegment] = []
        self.by_tile: dict[tuple[int, int], list[int]] = {}
        for tile in sorted(map_.drivable_tiles(), key=lambda t: (t.j, t.i)):
            ids = []
            for entry in tile.open_edges:
                for exit_ in tile.open_edges:
                    if exit_ != entry:
                        seg = _segment_between(len(segments), tile.i, tile.j, map_.tile_size, entry, exit_, geometry)
                        segments.append(seg)
                        ids.append(seg.index)
            self.by_tile[(tile.i, tile.j)] = ids
        self.segments: tuple[LaneSegment, ...] = tuple(segments)

    def successors(self, index: int) -> list[int]:
        """Segments that continue this one on the neighbouring tile."""
        seg = self.segments[index]
        dx, dy = seg.exit.unit
        nxt = (seg.tile[0] + dx, seg.tile[1] + dy)
        return [k for k in self.by_tile.get(nxt, []) if self.segments[k].entry == seg.exit.opposite]

    def predecessors(self, index: int) -> list[int]:
        seg = self.segments[index]
        dx, dy = seg.entry.unit
        prv = (seg.tile[0] + dx, seg.tile[1] + dy)
        return [k for k in self.by_tile.get(prv, []) if self.segments[k].exit == seg.entry.opposite]

    @cached_property
    def arrays(self) -> LaneArrays:
        return LaneArrays.build(self)


@dataclass(frozen=True)
class LaneArrays:
    """The network as plain arrays, the form the Numba kernels read.

    - ``seg_kind`` (n,) int8: SegmentKind.
    - ``seg_f`` (n, 8) float64: x0, y0, heading0, length, cx, cy, radius, phi0.
    - ``tile_segs`` (W, H, 12) int32: segment ids of each tile, -1 padded.
    - ``tile_kind`` (W, H) int8: index into ``DRIVABLE_KINDS``; -1 non-drivable, -2 empty.
    - ``tile_orient`` (W, H) int8: Direction; ``tile_base`` (W, H) int8: ground material
      (0 road, 1 grass, 2 floor, 3 asphalt, -1 none).
    - ``curve_corner`` (W, H, 2) float64: for curve tiles, the corner the road turns around.
    """

    seg_kind: np.ndarray
    seg_f: np.ndarray
    tile_segs: np.ndarray
    tile_kind: np.ndarray
    tile_orient: np.ndarray
    tile_base: np.ndarray
    curve_corner: np.ndarray
    tile_size: float
    lane_half_width: float

    @staticmethod
    def build(net: LaneNetwork) -> LaneArrays:
        m = net.map
        n = len(net.segments)
        seg_kind = np.array([s.kind for s in net.segments], dtype=np.int8)
        seg_f = np.zeros((max(n, 1), 8))
        for s in net.segments:
            phi0 = math.atan2(s.y0 - s.cy, s.x0 - s.cx) if s.kind != SegmentKind.STRAIGHT else 0.0
            seg_f[s.index] = (s.x0, s.y0, s.heading0, s.length, s.cx, s.cy, s.radius, phi0)
        tile_segs = np.full((m.width, m.height, LaneNetwork.MAX_SEGMENTS_PER_TILE), -1, dtype=np.int32)
        tile_kind = np.full((m.width, m.height), -2, dtype=np.int8)
        tile_orient = np.zeros((m.width, m.height), dtype=np.int8)
        tile_base = np.full((m.width, m.height), -1, dtype=np.int8)
        curve_corner = np.zeros((m.width, m.height, 2))
        base_codes = {"grass": 1, "floor": 2, "asphalt": 3}
        for t in m.iter_tiles():
            tile_orient[t.i, t.j] = int(t.orientation)
            if t.drivable:
                tile_kind[t.i, t.j] = DRIVABLE_KINDS.index(t.kind)
                tile_base[t.i, t.j] = 0
                ids = net.by_tile[(t.i, t.j)]
                tile_segs[t.i, t.j, : len(ids)] = ids
                if t.kind.startswith("curve"):
                    a, b = t.open_edges
                    curve_corner[t.i, t.j] = (
                        (t.i + 0.5 + 0.5 * (a.unit[0] + b.unit[0])) * m.tile_size,
                        (t.j + 0.5 + 0.5 * (a.unit[1] + b.unit[1])) * m.tile_size,
                    )
            else:
                tile_kind[t.i, t.j] = -1
                tile_base[t.i, t.j] = base_codes[GROUND_KINDS[t.kind]]
        return LaneArrays(
            seg_kind, seg_f, tile_segs, tile_kind, tile_orient, tile_base, curve_corner,
            m.tile_size, 0.5 * net.geometry.lane_width * m.tile_size,
        )
