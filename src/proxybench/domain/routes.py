"""Routes through intersections: which exit each robot takes, and the lane pose along that exit.

Through a 3-way or 4-way tile the lanes of one entry overlap (straight on, left, right), so the pose
alone cannot say which of them the robot is in. A *route* names it, one exit per intersection visit,
and the lane pose on the intersection tile is then measured against that lane: a privileged agent
following the lane pose drives the route, and the metrics measure the run against it.

The rule, live (:class:`RouteTracker`, one per simulator):

- When a robot comes within ``CHOICE_DISTANCE`` of a stop line (the entry of an intersection tile)
  along its lane, the exit is chosen among those the tile allows from that entry: the next turn of the
  robot's *plan* (a list of ``left`` / ``straight`` / ``right``: the k-th intersection approached takes
  the k-th turn), else a draw from the episode seed (its own random stream, so a batch of robots and a
  single robot draw alike). A planned turn the tile does not allow is replaced by a draw, and logged.
- On the intersection tile the lane pose is measured against the chosen lane (it is *pinned*) until
  the robot leaves the tile. A robot found on an intersection without a choice (it started there, or
  arrived unexpectedly) chooses at once among the lanes of the entry it fits best.

After the run (:func:`pin_route`, used by every trajectory, simulated or recorded): a visit to an
intersection tile uses the lane the simulator chose for it when the trajectory carries one (privileged
agents, which were told the route); otherwise the route is *whichever exit the robot took*: the lane
from the edge it came in through to the edge it left through (camera agents are free, as in AIDO's
LF-I). A visit that never left the tile, or left through a closed edge, keeps the lane of its entry that
best fits its last pose.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from proxybench.domain.lane_pose import LP, lane_pose_on_segment_into, lane_poses, lane_poses_on_segments
from proxybench.domain.lanes import LaneNetwork, SegmentKind
from proxybench.domain.maps import Direction

__all__ = [
    "CHOICE_DISTANCE", "INTERSECTION_KINDS", "TURNS", "RouteGraph", "RouteInfo", "RouteTracker",
    "check_turns", "given_route_samples", "pin_route", "route_columns", "route_issues",
]

#: tile kinds with stop lines and more than one exit per entry
INTERSECTION_KINDS = ("3way_left", "3way_right", "4way")
#: the turns a plan may name
TURNS = ("left", "straight", "right")
#: distance [m] before the stop line (along the lane) at which a robot's exit is chosen
CHOICE_DISTANCE = 0.30
_ROUTE_STREAM = 0x726F757465  # spawn key of the route draws: independent of the start-pose draws


def check_turns(turns: Sequence[str]) -> tuple[str, ...]:
    """The plan as a tuple, or ValueError naming the first entry that is not a turn."""
    for k, turn in enumerate(turns):
        if turn not in TURNS:
            raise ValueError(f"turn {k}: {turn!r} is not one of {', '.join(TURNS)}")
    return tuple(turns)


class RouteGraph:
    """The lane network seen as a route graph: per-segment tile, entry, length and successors."""

    def __init__(self, net: LaneNetwork):
        self.net = net
        m = net.map
        self.mask = np.zeros((m.width, m.height), dtype=bool)
        for t in m.drivable_tiles():
            self.mask[t.i, t.j] = t.kind in INTERSECTION_KINDS
        segs = net.segments
        self.tile = np.array([s.tile for s in segs], dtype=np.int64).reshape(-1, 2)
        self.entry = np.array([int(s.entry) for s in segs], dtype=np.int64)
        self.exit = np.array([int(s.exit) for s in segs], dtype=np.int64)
        self.length = np.array([s.length for s in segs])
        self.turn = tuple(SegmentKind.NAMES[s.kind] for s in segs)
        self.successors = tuple(tuple(net.successors(k)) for k in range(len(segs)))
        #: the segment ends at a stop line: its successors lie on an intersection tile
        self.leads_to_stop = np.array([bool(nx) and self.is_intersection(*self.tile[nx[0]]) for nx in self.successors],
                                      dtype=bool)
        self.active = bool(self.mask.any())

    def is_intersection(self, i: int, j: int) -> bool:
        return 0 <= i < self.mask.shape[0] and 0 <= j < self.mask.shape[1] and bool(self.mask[i, j])

    def on_tile(self, k: int, i: int, j: int) -> bool:
        return k >= 0 and self.tile[k, 0] == i and self.tile[k, 1] == j

    def entry_lanes(self, i: int, j: int, entry: int) -> list[int]:
        """Segments of tile (i, j) entering through edge ``entry``, in the network's order."""
        return [k for k in self.net.by_tile.get((i, j), []) if self.entry[k] == entry]

    def visit_mask(self, ti: np.ndarray, tj: np.ndarray) -> np.ndarray:
        """Per sample: on an intersection tile."""
        w, h = self.mask.shape
        inside = (ti >= 0) & (tj >= 0) & (ti < w) & (tj < h)
        out = np.zeros(ti.shape, dtype=bool)
        out[inside] = self.mask[ti[inside], tj[inside]]
        return out


@dataclass(frozen=True)
class RouteInfo:
    """What a privileged agent is told about its route.

    ``next_turn``: the turn chosen at the intersection ahead or being crossed (None until chosen);
    ``stop_distance`` [m]: along the lane to the stop line ahead, ``inf`` when the lane ends at none;
    ``in_intersection``: the robot is on an intersection tile.
    """

    next_turn: str | None
    stop_distance: float
    in_intersection: bool


class RouteTracker:
    """Route choices of N robots, applied to their lane poses every frame (see the module rule)."""

    def __init__(self, net: LaneNetwork, n: int):
        self.graph = RouteGraph(net)
        self.arrays = net.arrays
        self.n = n
        self.pin = np.full(n, -1, dtype=np.int64)  # lane pinned on the intersection being crossed
        self.next = np.full(n, -1, dtype=np.int64)  # lane chosen at the intersection ahead
        self._rng = [np.random.default_rng(i) for i in range(n)]
        self._plan: list[tuple[str, ...]] = [()] * n
        self._cursor = [0] * n
        #: per robot, every choice made this episode: t [s], tile, entry, turn, segment, source
        self.choices: list[list[dict[str, Any]]] = [[] for _ in range(n)]

    @property
    def active(self) -> bool:
        return self.graph.active

    def reset(self, i: int, seed: int, plan: Sequence[str] | None = None) -> None:
        """New episode of robot ``i``: draws from ``seed``; ``plan`` fixes its first turns."""
        self._rng[i] = np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=(_ROUTE_STREAM,)))
        self._plan[i] = check_turns(plan or ())
        self._cursor[i] = 0
        self.pin[i] = -1
        self.next[i] = -1
        self.choices[i] = []

    def update(self, idx: np.ndarray, poses: np.ndarray, wheel_half: np.ndarray, rows: np.ndarray,
               times: np.ndarray) -> None:
        """Choose exits and pin the lane-pose ``rows`` (one per robot in ``idx``) on intersection tiles."""
        if not self.graph.active:
            return
        for n, i in enumerate(np.asarray(idx).reshape(-1)):
            self._update_one(int(i), poses[n], float(wheel_half[n]), rows[n], float(times[n]))

    def _update_one(self, i: int, pose: np.ndarray, wheel_half: float, row: np.ndarray, t: float) -> None:
        g = self.graph
        if row[LP.VALID] < 0.5:
            return
        ti, tj = int(row[LP.TILE_I]), int(row[LP.TILE_J])
        if g.mask[ti, tj]:
            if not g.on_tile(int(self.pin[i]), ti, tj):
                entry = int(g.entry[int(row[LP.SEGMENT])])
                nxt = int(self.next[i])
                if g.on_tile(nxt, ti, tj) and g.entry[nxt] == entry:
                    self.pin[i] = nxt
                else:
                    self.pin[i] = self._choose(i, g.entry_lanes(ti, tj, entry), t)
                self.next[i] = -1
            a = self.arrays
            lane_pose_on_segment_into(pose[0], pose[1], pose[2], wheel_half, int(self.pin[i]), a.seg_kind, a.seg_f,
                                      a.tile_segs, a.tile_kind, a.curve_corner, a.tile_size, a.lane_half_width, row)
        else:
            self.pin[i] = -1
        cur = int(row[LP.SEGMENT])
        if cur < 0 or not g.leads_to_stop[cur] or g.length[cur] - row[LP.ALONG] > CHOICE_DISTANCE:
            return
        ahead = g.successors[cur]
        if int(self.next[i]) not in ahead:
            self.next[i] = self._choose(i, list(ahead), t)

    def _choose(self, i: int, lanes: list[int], t: float) -> int:
        g = self.graph
        turns = [g.turn[k] for k in lanes]
        plan, c = self._plan[i], self._cursor[i]
        if c < len(plan):
            self._cursor[i] += 1
            if plan[c] in turns:
                k, source = lanes[turns.index(plan[c])], "plan"
            else:
                k = lanes[int(self._rng[i].integers(len(lanes)))]
                source = f"random (planned turn {c} {plan[c]!r} not allowed here)"
        else:
            k, source = lanes[int(self._rng[i].integers(len(lanes)))], "random"
        self.choices[i].append({"t": t, "tile": [int(v) for v in g.tile[k]], "entry": Direction(g.entry[k]).name,
                                "turn": g.turn[k], "segment": k, "source": source})
        return k

    def info(self, i: int, row: np.ndarray) -> RouteInfo:
        """Robot ``i``'s route as its agent may see it, from its (pinned) lane-pose ``row``."""
        g = self.graph
        k = int(self.pin[i]) if self.pin[i] >= 0 else int(self.next[i])
        cur = int(row[LP.SEGMENT]) if row[LP.VALID] > 0.5 else -1
        stop = float(g.length[cur] - row[LP.ALONG]) if cur >= 0 and g.leads_to_stop[cur] else math.inf
        inside = cur >= 0 and g.is_intersection(int(row[LP.TILE_I]), int(row[LP.TILE_J]))
        return RouteInfo(g.turn[k] if k >= 0 else None, stop, inside)


def given_route_samples(net: LaneNetwork | RouteGraph, pose: np.ndarray, pins: np.ndarray, nexts: np.ndarray,
                        substeps: int) -> np.ndarray:
    """Per trajectory sample, the lane the tracker had chosen for the tile the sample is on (-1: none).

    ``pins`` / ``nexts`` (F,) are the tracker's lanes at the start of each frame; sample 0 is the start
    pose and samples ``1 + f·substeps … (f+1)·substeps`` are frame f's physics ticks.
    """
    g = net if isinstance(net, RouteGraph) else RouteGraph(net)
    ts = g.net.map.tile_size
    frame = np.clip((np.arange(pose.shape[0]) - 1) // substeps, 0, max(len(pins) - 1, 0))
    ti = np.floor(pose[:, 0] / ts).astype(np.int64)
    tj = np.floor(pose[:, 1] / ts).astype(np.int64)
    out = np.full(pose.shape[0], -1, dtype=np.int64)
    if not len(pins):
        return out
    for cand in (np.asarray(nexts)[frame], np.asarray(pins)[frame]):  # the pin wins where both match
        ok = cand >= 0
        c = np.where(ok, cand, 0)
        ok &= (g.tile[c, 0] == ti) & (g.tile[c, 1] == tj)
        out[ok] = cand[ok]
    return out


def _edge_towards(ti: np.ndarray, tj: np.ndarray, a: int, b: int) -> int | None:
    """The edge of sample a's tile that leads to sample b's tile, if the two tiles are neighbours."""
    d = (int(ti[b] - ti[a]), int(tj[b] - tj[a]))
    return next((int(e) for e in Direction if e.unit == d), None)


def pin_route(net: LaneNetwork | RouteGraph, pose: np.ndarray, lane: np.ndarray, wheel_distance: float = 0.102,
              given: np.ndarray | None = None) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """Pin every intersection visit of a trajectory to its route lane (see the module rule).

    ``lane`` (T, LP.N) is rewritten in place on intersection tiles; returns the route lane per sample
    (-1 off intersections) and one record per visit: first ``sample``, tile, entry, exit, turn, segment, rule.
    """
    g = net if isinstance(net, RouteGraph) else RouteGraph(net)
    out = np.full(len(lane), -1, dtype=np.int64)
    if not g.active or not len(lane):
        return out, []
    ti, tj = lane[:, LP.TILE_I].astype(np.int64), lane[:, LP.TILE_J].astype(np.int64)
    on = g.visit_mask(ti, tj) & (lane[:, LP.VALID] > 0.5)
    change = np.r_[True, (ti[1:] != ti[:-1]) | (tj[1:] != tj[:-1]) | (on[1:] != on[:-1])]
    starts = np.flatnonzero(on & change)
    visits = []
    for a in starts:
        b = a + 1
        while b < len(lane) and on[b] and not change[b]:
            b += 1
        seg, rule, entry, exit_ = _visit_lane(g, pose, lane, ti, tj, a, b, given)
        if seg >= 0:
            lane[a:b] = lane_poses_on_segments(g.net, pose[a:b], np.full(b - a, seg), wheel_distance)
            out[a:b] = seg
        visits.append({"sample": int(a), "tile": [int(ti[a]), int(tj[a])],
                       "entry": None if entry is None else Direction(entry).name,
                       "exit": None if exit_ is None else Direction(exit_).name,
                       "turn": g.turn[seg] if seg >= 0 else None, "segment": int(seg), "rule": rule})
    return out, visits


def _visit_lane(g: RouteGraph, pose: np.ndarray, lane: np.ndarray, ti: np.ndarray, tj: np.ndarray, a: int, b: int,
                given: np.ndarray | None) -> tuple[int, str, int | None, int | None]:
    """(lane, rule, entry edge, exit edge) of the visit to an intersection over samples [a, b)."""
    i, j = int(ti[a]), int(tj[a])
    entry = _edge_towards(ti, tj, a, a - 1) if a > 0 else None
    if entry is None:
        entry = int(g.entry[int(lane[a, LP.SEGMENT])])
    exit_ = _edge_towards(ti, tj, b - 1, b) if b < len(lane) else None
    if given is not None:
        chosen = [int(k) for k in given[a:b] if g.on_tile(int(k), i, j)]
        if chosen:
            return chosen[0], "chosen", entry, exit_
    lanes = g.entry_lanes(i, j, entry)
    if not lanes:  # came in through a closed edge: no lane to pin to
        return -1, "best-fit", entry, exit_
    taken = [k for k in lanes if g.exit[k] == exit_]
    if taken:
        return taken[0], "taken", entry, exit_
    rows = lane_poses_on_segments(g.net, np.repeat(pose[b - 1][None], len(lanes), axis=0), np.array(lanes), 0.0)
    cost = np.abs(rows[:, LP.HEADING_ERROR]) + np.abs(rows[:, LP.LATERAL]) * 2.0 / g.net.map.tile_size
    return lanes[int(np.argmin(cost))], "best-fit", entry, exit_


def route_columns(graph: RouteGraph, lane: np.ndarray) -> dict[str, np.ndarray]:
    """Per-sample ``stop_distance`` [m] and ``on_route`` (0/1) of a pinned trajectory.

    ``stop_distance``: along the robot's lane to the stop line it ends at (NaN where the lane ends at
    none). ``on_route``: the robot's lane continues the route driven so far, i.e. it is the last lane on
    the route or one of its successors (the pinned one on an intersection); a wrong exit or a turn
    back leaves the route until the robot is on it again.
    """
    g = graph
    on = np.zeros(len(lane))
    if not len(g.length):
        return {"stop_distance": np.full(len(lane), np.nan), "on_route": on}
    valid = lane[:, LP.VALID] > 0.5
    seg = np.where(valid, lane[:, LP.SEGMENT], -1).astype(np.int64)
    safe = np.maximum(seg, 0)
    stop = np.where((seg >= 0) & g.leads_to_stop[safe], g.length[safe] - lane[:, LP.ALONG], np.nan)
    last = -1
    for k in np.flatnonzero(seg >= 0):
        s = int(seg[k])
        if last < 0 or s == last or s in g.successors[last]:
            on[k] = 1.0
            last = s
    return {"stop_distance": stop, "on_route": on}


def route_issues(net: LaneNetwork | RouteGraph, pose: tuple[float, float, float],
                 turns: Sequence[str]) -> list[tuple[int, str]]:
    """Follow the lanes from a start pose, taking ``turns`` at the intersections met; ``(turn index,
    problem)`` for a turn the map does not allow where it would be taken (the walk stops there).

    This is the route a robot that keeps its lane drives; it lets a benchmark reject a plan before
    running it. Turns beyond a dead end (a road leaving the map) are never reached and not checked.
    """
    g = net if isinstance(net, RouteGraph) else RouteGraph(net)
    row = lane_poses(g.net, np.array([pose], dtype=float))[0]
    if row[LP.VALID] < 0.5 or not turns:
        return []
    cur, k, since = int(row[LP.SEGMENT]), 0, 0
    here = [int(v) for v in g.tile[cur]]
    options = g.entry_lanes(*here, int(g.entry[cur])) if g.is_intersection(*here) else [cur]
    while k < len(turns) and since <= len(g.length):
        if len(options) > 1 or g.is_intersection(*[int(v) for v in g.tile[options[0]]]):
            names = [g.turn[s] for s in options]
            i, j = (int(v) for v in g.tile[options[0]])
            if turns[k] not in names:
                kind = g.net.map.tile(i, j).kind
                entry = Direction(g.entry[options[0]]).name
                return [(k, f"{turns[k]!r} is not possible at the {kind} tile ({i}, {j}) entered from {entry} "
                            f"(possible: {', '.join(names)})")]
            cur, k, since = options[names.index(turns[k])], k + 1, 0
        else:
            cur, since = options[0], since + 1
        options = list(g.successors[cur])
        if not options:
            break
    return []
