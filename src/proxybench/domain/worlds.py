"""Per-episode worlds of a batched simulator: where the NPC robots live, what each robot sees and can hit.

A simulator of N egos has N worlds. World w holds ego w, the NPC robots and pedestrians of its
``npcs.Traffic`` and the extra duckies of its θ (``extra_duckies`` of them beside the road, at spots drawn
from ``object_seed``). The NPC robots are rows N.. of the simulator's arrays, stepped by the same physics
call as the egos (``Worlds.robot_lo[w] .. robot_hi[w]`` are world w's rows).

Every frame, ``moving_prims`` lays out the primitives of all worlds in one array, world by world (extras,
pedestrians at the world's time, NPC robots at their poses); ``ranges`` tells the renderer which rows
each robot sees (its world's, less its own body), and ``world_collisions`` checks every robot against its
own world only, at every physics tick. So robot i of a batch sees and hits exactly what it would alone.

An NPC robot that leaves the road or touches anything stops for good (the simulator zeroes its wheel
commands from the next frame): it stays where it came to rest, visible and solid, like a broken-down
vehicle in a real lab.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numba as nb
import numpy as np

from proxybench.domain.apriltags import ROOF_TAG_BASE
from proxybench.domain.lane_pose import point_on_road
from proxybench.domain.lanes import LaneNetwork
from proxybench.domain.maps import MapObject
from proxybench.domain.npcs import PedestrianArrays, Traffic, pedestrian_xy
from proxybench.domain.objects import (
    CF_MARGIN,
    DUCKIE_MARGIN,
    PF_COS,
    PF_SIN,
    PF_X,
    PF_Y,
    ROBOT_MARGIN,
    ObjectArrays,
    footprint_distance,
    object_primitives,
    pack_objects,
    robot_primitives,
)
from proxybench.domain.params import DomainParams

__all__ = ["FAULT_SPEED", "HIT_KINDS", "Worlds", "extra_duckie_spots", "robot_contacts", "world_collisions"]

#: what a robot hit, by ``Simulator.hit_kind`` code (0: nothing)
HIT_KINDS = ("", "map object", "duckie", "pedestrian", "robot")
_HIT_DUCKIE, _HIT_PEDESTRIAN, _HIT_ROBOT = 2, 3, 4


@nb.njit(cache=True)
def pedestrians_at(times, scale, ped_world, pts, cum, npts, speed, delay, mode, out):
    """``out[q]`` = (x, y) of pedestrian q at its world's time ``times[ped_world[q]]``."""
    for q in range(ped_world.shape[0]):
        w = ped_world[q]
        x, y = pedestrian_xy(q, times[w], scale[w], pts, cum, npts, speed, delay, mode)
        out[q, 0] = x
        out[q, 1] = y


@nb.njit(cache=True)
def world_collisions(
    trace, tick0, dt, row_world, robot_lo, robot_hi, extra_cols, extra_lo, extra_hi,
    ped_lo, ped_hi, pts, cum, npts, speed, delay, mode, ped_radius, scale, only_world, flags, kind,
):
    """Flag robots (rows of ``trace`` (R, S, ≥2), positions after each of S ticks) that touch an object of their
    own world: an extra duckie (``extra_cols``), a pedestrian at that tick's time ((tick0 + k + 1) dt), or
    another robot of the world (the ego is row w, the NPC robots rows ``robot_lo[w] .. robot_hi[w] - 1``).

    Sticky like ``objects.collision_check``; ``kind[r]`` records what was hit (``HIT_KINDS``). Only world
    ``only_world`` is checked when it is >= 0.
    """
    for r in range(trace.shape[0]):
        w = row_world[r]
        if flags[r] or (only_world >= 0 and w != only_world):
            continue
        for k in range(trace.shape[1]):
            x = trace[r, k, 0]
            y = trace[r, k, 1]
            for m in range(extra_lo[w], extra_hi[w]):
                if footprint_distance(x, y, extra_cols[m]) < extra_cols[m, CF_MARGIN]:
                    kind[r] = _HIT_DUCKIE
            t = (tick0[r] + k + 1) * dt
            for q in range(ped_lo[w], ped_hi[w]):
                px, py = pedestrian_xy(q, t, scale[w], pts, cum, npts, speed, delay, mode)
                if math.sqrt((x - px) ** 2 + (y - py) ** 2) - ped_radius < DUCKIE_MARGIN:
                    kind[r] = _HIT_PEDESTRIAN
            for o in range(robot_lo[w] - 1, robot_hi[w]):
                o2 = w if o == robot_lo[w] - 1 else o  # the ego first, then the NPC rows
                if o2 != r and math.sqrt((x - trace[o2, k, 0]) ** 2 + (y - trace[o2, k, 1]) ** 2) < ROBOT_MARGIN:
                    kind[r] = _HIT_ROBOT
            if kind[r] != 0:
                flags[r] = True
                break


#: [m/s] a robot moving towards another faster than this at contact is at fault (a standing robot never is)
FAULT_SPEED = 0.01


@nb.njit(cache=True)
def robot_contacts(trace, n, partner, fault):
    """First contact of each ego (rows ``0 .. n - 1`` of ``trace`` (R, S, ≥5): x, y, θ, v after each of S ticks)
    with another ego of a shared world: centres closer than ``ROBOT_MARGIN``. Sticky: ``partner[i]`` (-1: none yet)
    gets the other robot, ``fault[i]`` whether robot i was moving towards it (its velocity's component along the
    line from its centre to the other's exceeds ``FAULT_SPEED``). A head-on contact makes both at fault."""
    for k in range(trace.shape[1]):
        for i in range(n):
            for j in range(i + 1, n):
                if partner[i] >= 0 and partner[j] >= 0:
                    continue
                dx = trace[j, k, 0] - trace[i, k, 0]
                dy = trace[j, k, 1] - trace[i, k, 1]
                d = math.sqrt(dx * dx + dy * dy)
                if d >= ROBOT_MARGIN:
                    continue
                ux, uy = (dx / d, dy / d) if d > 0.0 else (0.0, 0.0)
                for a, b, sx, sy in ((i, j, ux, uy), (j, i, -ux, -uy)):
                    if partner[a] < 0:
                        partner[a] = b
                        v = trace[a, k, 3]
                        fault[a] = v * (math.cos(trace[a, k, 2]) * sx + math.sin(trace[a, k, 2]) * sy) > FAULT_SPEED


def extra_duckie_spots(net: LaneNetwork, colliders: np.ndarray, count: int, seed: int) -> np.ndarray:
    """(≤ count, 2) spots [m] just beside the road (5–20 cm off its edge), clear of map objects and of each other.

    Drawn from ``seed`` alone: the same θ puts them at the same spots in every episode.
    """
    if count <= 0:
        return np.zeros((0, 2))
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xD0C]))
    a = net.arrays
    plain = [s for s in net.segments if net.map.tile(*s.tile).kind in ("straight", "curve_left", "curve_right")]
    segs = plain or list(net.segments)
    lengths = np.array([s.length for s in segs])
    edge = (0.5 - net.geometry.lane_offset) * net.map.tile_size  # lane centre → road edge, on its right
    spots: list[tuple[float, float]] = []
    for _ in range(count):
        for _try in range(100):
            seg = segs[int(rng.choice(len(segs), p=lengths / lengths.sum()))]
            x, y = seg.position(float(rng.uniform(0.0, seg.length)), -(edge + float(rng.uniform(0.05, 0.2))))
            if point_on_road(x, y, a.tile_kind, a.curve_corner, a.tile_size):
                continue
            if any(math.hypot(x - c[0], y - c[1]) < 0.25 for c in colliders) or any(
                    math.hypot(x - u, y - v) < 0.12 for u, v in spots):
                continue
            spots.append((x, y))
            break
    return np.array(spots, dtype=np.float64).reshape(-1, 2)


class Worlds:
    """The N worlds of a simulator: NPC robot rows, the moving primitives of every world, their collisions.

    ``traffic[w]`` is world w's NPCs. Rows: ``0 .. n - 1`` are the egos, ``n .. rows - 1`` the NPC robots,
    world by world (``robot_world`` (K,) says whose).
    """

    def __init__(self, net: LaneNetwork, static: ObjectArrays, traffic: Sequence[Traffic], n: int,
                 shared_tags: Sequence[int] | None = None):
        if len(traffic) != n:
            raise ValueError(f"{len(traffic)} NPC sets for {n} robots")
        if shared_tags is not None and (len(shared_tags) != n or any(not t.empty for t in traffic)):
            raise ValueError(f"a shared world of {n} robots takes one roof tag per robot ({len(shared_tags)} given) "
                             "and no npcs: its robots are each other's traffic")
        self.net, self.static, self.n = net, static, n
        #: shared world (a lab's robots): the egos are one world, each wearing its own roof tag; None: N worlds
        self.shared_tags = None if shared_tags is None else tuple(int(t) for t in shared_tags)
        self.traffic = tuple(traffic)
        per_world = [len(t.robots) for t in traffic]
        self.robot_world = np.repeat(np.arange(n), per_world).astype(np.int64)
        self.k = int(self.robot_world.size)
        self.rows = n + self.k
        self.row_world = np.concatenate([np.arange(n), self.robot_world]).astype(np.int64)
        starts = n + np.concatenate([[0], np.cumsum(per_world)]).astype(np.int64)
        self.robot_lo, self.robot_hi = starts[:-1].copy(), starts[1:].copy()
        self.robot_specs = [r for t in traffic for r in t.robots]
        self.robot_scale = np.array([r.speed_scale for r in self.robot_specs], dtype=np.float64)
        peds = [p for t in traffic for p in t.pedestrians]
        self.ped_world = np.repeat(np.arange(n), [len(t.pedestrians) for t in traffic]).astype(np.int64)
        pstarts = np.concatenate([[0], np.cumsum([len(t.pedestrians) for t in traffic])]).astype(np.int64)
        self.ped_lo, self.ped_hi = pstarts[:-1].copy(), pstarts[1:].copy()
        self.peds = PedestrianArrays.pack(peds)
        duck = pack_objects([MapObject("duckie", 0.0, 0.0)])
        self._duck_prims, self.ped_radius = duck.prims, float(duck.colliders[0, 4])
        self._bot_prims = robot_primitives(ROOF_TAG_BASE + 1)  # body and roof tag (each NPC robot's own id)
        assert object_primitives(MapObject("duckiebot", 0.0, 0.0))[1], "NPC robots collide as robot-like objects"
        self.speed_scale = np.ones(n)
        self._extras = [pack_objects(())] * n
        self._extra_key: list[tuple[int, int] | None] = [None] * n
        self._layout()

    @property
    def active(self) -> bool:
        """Anything beyond the map's own objects in any world (else the simulator skips all of this)."""
        return self.k > 0 or self.ped_world.size > 0 or self.extra_cols.shape[0] > 0 or self.shared_tags is not None

    def set_params(self, w: int, p: DomainParams) -> None:
        """World w follows θ = ``p``: NPC speed factor and extra duckies."""
        self.speed_scale[w] = p.npc_speed_scale
        if self.shared_tags is not None and p.extra_duckies:
            raise ValueError("a shared world takes no extra duckies (θ extra_duckies must be 0)")
        key = (p.extra_duckies, p.object_seed)
        if key != self._extra_key[w]:
            spots = extra_duckie_spots(self.net, self.static.colliders, *key)
            self._extras[w] = pack_objects([MapObject("duckie", float(x), float(y)) for x, y in spots])
            self._extra_key[w] = key
            self._layout()

    def _layout(self) -> None:
        """Rows of ``moving``: per world its extras, then its pedestrians, then its NPC robots' bodies."""
        rows, lo, ped_row, bot_row, cols, c_lo = [], [], [], [], [], []
        n_rows = n_cols = 0
        for w in range(self.n):
            lo.append(n_rows)
            c_lo.append(n_cols)
            rows.append(self._extras[w].prims)
            cols.append(self._extras[w].colliders)
            n_rows += self._extras[w].prims.shape[0]
            n_cols += self._extras[w].colliders.shape[0]
            for _ in range(self.ped_lo[w], self.ped_hi[w]):
                ped_row.append(n_rows)
                rows.append(self._duck_prims)
                n_rows += self._duck_prims.shape[0]
            for j in range(self.robot_hi[w] - self.robot_lo[w]):
                bot_row.append(n_rows)
                rows.append(robot_primitives(ROOF_TAG_BASE + 1 + j))
                n_rows += self._bot_prims.shape[0]
        self.world_lo = np.array(lo, dtype=np.int64)
        self.world_hi = np.append(self.world_lo[1:], n_rows).astype(np.int64)
        self.moving = np.concatenate(rows) if rows else np.zeros((0, self.static.prims.shape[1]))
        self._ped_row = np.array(ped_row, dtype=np.int64)
        self._bot_row = np.array(bot_row, dtype=np.int64)
        self.extra_cols = np.concatenate(cols) if cols else np.zeros((0, self.static.colliders.shape[1]))
        self.extra_lo = np.array(c_lo, dtype=np.int64)
        self.extra_hi = np.append(self.extra_lo[1:], n_cols).astype(np.int64)
        self._ped_xy = np.zeros((self.ped_world.size, 2))
        nb_ = self._bot_prims.shape[0]
        if self.shared_tags is not None:
            self._shared_layout(nb_)
            return
        self.ranges = np.zeros((self.rows, 4), dtype=np.int64)
        self.ranges[:, 0] = self.world_lo[self.row_world]
        self.ranges[:, 1] = self.world_hi[self.row_world]
        self.ranges[self.n:, 2] = self._bot_row
        self.ranges[self.n:, 3] = self._bot_row + nb_

    def _shared_layout(self, nb_: int) -> None:
        """A shared world's ``moving``: every ego's body with its own roof tag; each ego sees them all but its own."""
        self._tpl = [robot_primitives(t) for t in self.shared_tags]
        self.moving = np.concatenate(self._tpl)
        self.world_lo = np.zeros(self.n, dtype=np.int64)
        self.world_hi = np.full(self.n, self.moving.shape[0], dtype=np.int64)
        self._ego_row = np.arange(self.n, dtype=np.int64) * nb_
        self.ranges = np.zeros((self.rows, 4), dtype=np.int64)
        self.ranges[:, 0] = 0
        self.ranges[:, 1] = self.moving.shape[0]
        self.ranges[:, 2] = self._ego_row
        self.ranges[:, 3] = self._ego_row + nb_

    def moving_prims(self, state: np.ndarray, ticks: np.ndarray, dt: float) -> np.ndarray:
        """``moving`` with pedestrians at their worlds' times (``ticks`` (N,) × ``dt`` [s]) and NPC robots at
        their poses (``state`` rows n..); in a shared world, every ego at its pose (``state`` rows ..n)."""
        m = self.moving
        if self.shared_tags is not None:
            x, y, th = state[: self.n, 0], state[: self.n, 1], state[: self.n, 2]
            c, s = np.cos(th), np.sin(th)
            for j, p in enumerate(self._tpl[0]):
                _place(m, self._ego_row + j, x, y, c, s, p)
            return m
        if self.ped_world.size:
            a = self.peds
            pedestrians_at(ticks[: self.n] * dt, self.speed_scale, self.ped_world, a.pts, a.cum, a.npts, a.speed,
                           a.delay, a.mode, self._ped_xy)
            for j in range(self._duck_prims.shape[0]):
                m[self._ped_row + j, PF_X] = self._ped_xy[:, 0] + self._duck_prims[j, PF_X]
                m[self._ped_row + j, PF_Y] = self._ped_xy[:, 1] + self._duck_prims[j, PF_Y]
        if self.k:
            x, y, th = state[self.n:, 0], state[self.n:, 1], state[self.n:, 2]
            c, s = np.cos(th), np.sin(th)
            for j, p in enumerate(self._bot_prims):
                _place(m, self._bot_row + j, x, y, c, s, p)
        return m

    def collide(self, trace: np.ndarray, tick0: np.ndarray, dt: float, flags: np.ndarray, kind: np.ndarray,
                only_world: int = -1) -> None:
        """Run ``world_collisions`` for all rows (or one world's) over a physics trace (R, S, ≥2)."""
        a = self.peds
        world_collisions(trace, tick0, dt, self.row_world, self.robot_lo, self.robot_hi, self.extra_cols,
                         self.extra_lo, self.extra_hi, self.ped_lo, self.ped_hi, a.pts, a.cum, a.npts, a.speed,
                         a.delay, a.mode, self.ped_radius, self.speed_scale, only_world, flags, kind)

    def objects_of(self, w: int, state: np.ndarray, ticks: np.ndarray, dt: float) -> np.ndarray:
        """World w's extras and pedestrians as primitives (P, PF), for top-down views (a shared world has none)."""
        if self.shared_tags is not None:
            return np.zeros((0, self.moving.shape[1]))
        m = self.moving_prims(state, ticks, dt)
        keep = np.ones(self.world_hi[w] - self.world_lo[w], dtype=bool)
        for r in self._bot_row[(self.robot_world == w)]:
            keep[r - self.world_lo[w]: r - self.world_lo[w] + self._bot_prims.shape[0]] = False
        return m[self.world_lo[w]: self.world_hi[w]][keep].copy()


def _place(m: np.ndarray, rows, x: np.ndarray, y: np.ndarray, c: np.ndarray, s: np.ndarray, p: np.ndarray) -> None:
    """Primitive ``p`` (in a robot's frame) placed at each robot's pose (x, y, heading cos c / sin c) in ``m``'s
    ``rows``: one rigid transform for ego robots of a shared world and NPC robots alike."""
    m[rows, PF_X] = x + c * p[PF_X] - s * p[PF_Y]
    m[rows, PF_Y] = y + s * p[PF_X] + c * p[PF_Y]
    m[rows, PF_COS] = c * p[PF_COS] - s * p[PF_SIN]
    m[rows, PF_SIN] = s * p[PF_COS] + c * p[PF_SIN]
