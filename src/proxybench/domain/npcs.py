"""Other road users of an episode's world: NPC Duckiebots and pedestrian duckies.

Each episode of a batch has its own world (``proxybench.domain.worlds``): its robot (the *ego*), the NPC
robots and pedestrians of its ``Traffic`` and the extra duckies its θ asks for. This module holds what a
benchmark file describes and the motion laws; ``worlds`` lays them out for the compiled kernels.

- ``NpcRobot``: a Duckiebot driven by an agent (``driver``, a zoo agent name: the runner's business,
  the domain only receives its wheel commands). It starts at an explicit ``pose``, on a ``tile``,
  ``ahead`` of the ego along its lane, or anywhere on the lanes (drawn from the episode seed).
- ``Pedestrian``: a duckie walking a polyline of waypoints [m] at ``speed`` [m/s] after ``delay`` [s],
  in one of three modes: ``loop`` (back to the first waypoint and round again), ``back-and-forth``, or
  ``once`` (then it stays at the last waypoint). Its position is a function of the episode time alone
  (``pedestrian_xy``), so it is reproducible exactly and the same in a batch as alone.

>>> t = Traffic(pedestrians=(Pedestrian(((0.0, 0.0), (1.0, 0.0)), speed=0.5),))
>>> pedestrian_positions(t.pedestrians, 3.0)[0].tolist()  # 1.5 m walked: back at 0.5 m
[0.5, 0.0]
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numba as nb
import numpy as np

from proxybench.domain.lanes import LaneNetwork

__all__ = [
    "PEDESTRIAN_MODES",
    "NpcRobot",
    "Pedestrian",
    "PedestrianArrays",
    "Traffic",
    "npc_start",
    "pedestrian_positions",
    "pedestrian_xy",
]

PEDESTRIAN_MODES = ("loop", "back-and-forth", "once")
_LOOP, _BOUNCE, _ONCE = range(3)
#: an NPC robot drawn at random starts at least this far [m] from the ego, other robots and duckies
START_GAP = 0.35


@dataclass(frozen=True)
class NpcRobot:
    """An NPC Duckiebot: who drives it, where it starts, and a factor on its wheel commands.

    At most one of ``pose`` (x, y, θ) [m, m, rad], ``tile`` (i, j) (a lane point of that tile drawn from the
    episode seed) and ``ahead`` [m] (that far ahead of the ego's start along its lane) is given; with none,
    the start is drawn from all lanes. ``speed_scale`` multiplies its wheel commands (and so its speed and
    turn rate together: a steady turn keeps its curvature).
    """

    driver: str = "pid"
    pose: tuple[float, float, float] | None = None
    tile: tuple[int, int] | None = None
    ahead: float | None = None
    speed_scale: float = 1.0

    def __post_init__(self) -> None:
        given = [k for k in ("pose", "tile", "ahead") if getattr(self, k) is not None]
        if len(given) > 1:
            raise ValueError(f"an NPC robot starts by one rule; got {' and '.join(given)}")
        if self.ahead is not None and self.ahead <= 0:
            raise ValueError(f"ahead must be positive [m], got {self.ahead}")
        if not 0.0 <= self.speed_scale <= 3.0:
            raise ValueError(f"speed_scale must be in [0, 3], got {self.speed_scale}")


@dataclass(frozen=True)
class Pedestrian:
    """A duckie walking ``path`` (waypoints (x, y) [m], map frame) at ``speed`` [m/s] from ``delay`` [s] on."""

    path: tuple[tuple[float, float], ...]
    speed: float = 0.2
    delay: float = 0.0
    mode: str = "back-and-forth"

    def __post_init__(self) -> None:
        if not self.path:
            raise ValueError("a pedestrian needs at least one waypoint")
        if self.mode not in PEDESTRIAN_MODES:
            raise ValueError(f"mode must be one of {', '.join(PEDESTRIAN_MODES)}, got {self.mode!r}")
        if not (self.speed >= 0 and self.delay >= 0 and math.isfinite(self.speed) and math.isfinite(self.delay)):
            raise ValueError(f"speed and delay must be finite and >= 0, got {self.speed}, {self.delay}")


@dataclass(frozen=True)
class Traffic:
    """The NPC robots and pedestrians of one episode's world (hashable: it keys simulator caches)."""

    robots: tuple[NpcRobot, ...] = ()
    pedestrians: tuple[Pedestrian, ...] = ()

    @property
    def empty(self) -> bool:
        return not (self.robots or self.pedestrians)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able canonical form (for job keys and trajectory metadata)."""
        return {"robots": [asdict(r) for r in self.robots], "pedestrians": [asdict(p) for p in self.pedestrians]}


# -- pedestrians --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PedestrianArrays:
    """Pedestrians packed for the kernels: waypoints ``pts`` (Q, M, 2), ``cum`` (Q, M + 1) arc length at each
    waypoint and round the closing leg, ``npts``, ``speed``, ``delay``, ``mode`` (Q,)."""

    pts: np.ndarray
    cum: np.ndarray
    npts: np.ndarray
    speed: np.ndarray
    delay: np.ndarray
    mode: np.ndarray

    @staticmethod
    def pack(peds: Sequence[Pedestrian]) -> PedestrianArrays:
        m = max((len(p.path) for p in peds), default=1)
        q = len(peds)
        pts = np.zeros((q, m, 2))
        cum = np.zeros((q, m + 1))
        for k, p in enumerate(peds):
            xy = np.asarray(p.path, dtype=np.float64).reshape(-1, 2)
            pts[k, : len(xy)] = xy
            legs = np.linalg.norm(np.diff(np.vstack([xy, xy[:1]]), axis=0), axis=1)
            cum[k, 1 : len(xy) + 1] = np.cumsum(legs)
        return PedestrianArrays(
            pts, cum, np.array([len(p.path) for p in peds], dtype=np.int64),
            np.array([p.speed for p in peds], dtype=np.float64), np.array([p.delay for p in peds], dtype=np.float64),
            np.array([PEDESTRIAN_MODES.index(p.mode) for p in peds], dtype=np.int64),
        )


@nb.njit(cache=True)
def pedestrian_xy(q, t, scale, pts, cum, npts, speed, delay, mode):
    """(x, y) [m] of pedestrian ``q`` at episode time ``t`` [s], its speed multiplied by ``scale``."""
    m = npts[q]
    if m == 1 or t <= delay[q]:
        return pts[q, 0, 0], pts[q, 0, 1]
    d = speed[q] * scale * (t - delay[q])
    open_len = cum[q, m - 1]
    if mode[q] == _LOOP:
        d = d % cum[q, m] if cum[q, m] > 0.0 else 0.0
    elif mode[q] == _BOUNCE:
        d = d % (2.0 * open_len) if open_len > 0.0 else 0.0
        if d > open_len:
            d = 2.0 * open_len - d
    else:
        d = min(d, open_len)
    for k in range(m):
        end = cum[q, k + 1]
        if d <= end or k == m - 1:
            leg = end - cum[q, k]
            f = (d - cum[q, k]) / leg if leg > 0.0 else 0.0
            f = min(max(f, 0.0), 1.0)
            b = (k + 1) % m
            return pts[q, k, 0] + f * (pts[q, b, 0] - pts[q, k, 0]), pts[q, k, 1] + f * (pts[q, b, 1] - pts[q, k, 1])
    return pts[q, 0, 0], pts[q, 0, 1]


def pedestrian_positions(peds: Sequence[Pedestrian], t: float, scale: float = 1.0) -> np.ndarray:
    """(Q, 2) positions [m] of pedestrians at episode time ``t`` [s] (a Python view of ``pedestrian_xy``)."""
    a = PedestrianArrays.pack(peds)
    return np.array([pedestrian_xy(q, t, scale, a.pts, a.cum, a.npts, a.speed, a.delay, a.mode)
                     for q in range(len(peds))]).reshape(-1, 2)


# -- NPC robot starts ---------------------------------------------------------------------------------


def _start_segments(net: LaneNetwork, tile: tuple[int, int] | None) -> list:
    if tile is not None:
        segs = [net.segments[k] for k in net.by_tile.get(tuple(tile), [])]
        if not segs:
            raise ValueError(f"NPC start tile {tuple(tile)} has no lanes")
        return segs
    plain = [s for s in net.segments if net.map.tile(*s.tile).kind in ("straight", "curve_left", "curve_right")]
    return plain or list(net.segments)


def _along_lane(net: LaneNetwork, seg_index: int, s: float, ahead: float) -> tuple[float, float, float] | None:
    """The lane-centre pose ``ahead`` [m] further along from (segment, s), taking the first successor at forks."""
    seg = net.segments[seg_index]
    s += ahead
    while s > seg.length:
        nxt = net.successors(seg.index)
        if not nxt:
            return None
        s -= seg.length
        seg = net.segments[nxt[0]]
    x, y = seg.position(s, 0.0)
    return x, y, seg.heading_at(s)


def npc_start(
    net: LaneNetwork, spec: NpcRobot, rng: np.random.Generator, ego: tuple[float, float, float],
    ego_lane: tuple[int, float], occupied: np.ndarray,
) -> tuple[float, float, float]:
    """Start pose of an NPC robot. ``ego_lane`` = (segment, arc length) of the ego's start (segment -1 if off
    the lanes); ``occupied`` (M, 2) points a drawn start keeps ``START_GAP`` from (ego, robots, duckies)."""
    if spec.pose is not None:
        return spec.pose
    if spec.ahead is not None and ego_lane[0] >= 0:
        pose = _along_lane(net, ego_lane[0], ego_lane[1], spec.ahead)
        if pose is not None:
            return pose
    segs = _start_segments(net, spec.tile)
    lengths = np.array([s.length for s in segs])
    pose = ego
    for _ in range(200):
        seg = segs[int(rng.choice(len(segs), p=lengths / lengths.sum()))]
        s = float(rng.uniform(0.1, 0.9)) * seg.length
        x, y = seg.position(s, float(rng.uniform(-0.02, 0.02)))
        pose = (x, y, math.remainder(seg.heading_at(s) + float(rng.uniform(-0.1, 0.1)), 2 * math.pi))
        if occupied.shape[0] == 0 or np.min(np.hypot(occupied[:, 0] - x, occupied[:, 1] - y)) >= START_GAP:
            return pose
    return pose  # a crowded map: the last draw (it may start in a collision, which is then reported)
