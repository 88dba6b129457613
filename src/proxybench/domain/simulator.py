"""The batched simulator core: N Duckiebots on one map, stepped and rendered in compiled calls.

``Simulator`` holds every robot's state in arrays and advances all of them with one call per frame
(``physics_ticks``), computes their lane poses (``lane_poses_into``) and renders their camera frames
(``Renderer``). Robots are independent: robot i's episode depends only on its own parameters and seed,
never on the batch it runs in, so a batch of N equals N single simulators (tested).

The Gymnasium envs in ``proxybench.domain.env`` are thin layers over this class.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numba as nb
import numpy as np

from proxybench.domain.apriltags import ROOF_TAG_BASE
from proxybench.domain.dynamics import DYN_FIELDS, ST, TRACE_FIELDS, blur_poses, pack_dynamics, physics_ticks
from proxybench.domain.lane_pose import LP, lane_pose_into, point_on_road
from proxybench.domain.lanes import LaneNetwork
from proxybench.domain.maps import Map, load_map
from proxybench.domain.npcs import Traffic, npc_start
from proxybench.domain.objects import CF_MARGIN, collision_check, footprint_distance, pack_objects
from proxybench.domain.params import STRUCTURAL_FIELDS, DomainParams
from proxybench.domain.renderer import Renderer
from proxybench.domain.routes import RouteTracker
from proxybench.domain.worlds import HIT_KINDS, Worlds, robot_contacts

__all__ = ["Simulator", "StartDistribution", "episode_seed", "start_pose"]

_MASK64 = (1 << 64) - 1
_WHEEL_DISTANCE = DYN_FIELDS.index("wheel_distance")
_NO_TRACE = np.zeros((0, 0, len(TRACE_FIELDS)))
_NPC_STREAM = 0x4E5043  # spawn key of NPC start draws: independent of the ego's start and route draws
#: redraws of a random start that lands within a map object's collision margin plus this clearance [m]
_START_TRIES, _START_CLEARANCE = 50, 0.05


@nb.njit(cache=True)
def _lane_poses(poses, wheel_half, seg_kind, seg_f, tile_segs, tile_kind, curve_corner, ts, half_width, out):
    """Lane pose rows of N robots, each with its own wheel track."""
    for n in range(poses.shape[0]):
        lane_pose_into(
            poses[n, 0], poses[n, 1], poses[n, 2], wheel_half[n], seg_kind, seg_f, tile_segs, tile_kind,
            curve_corner, ts, half_width, out[n],
        )


def episode_seed(seed: int) -> int:
    """A well-mixed 64-bit stream id from a user seed (splitmix64), for noise and latency jitter."""
    z = (seed + 0x9E3779B97F4A7C15) & _MASK64
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & _MASK64
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & _MASK64
    return z ^ (z >> 31)


@dataclass(frozen=True)
class StartDistribution:
    """Where episodes start when no pose is given.

    A lane segment of a straight or curve tile is drawn with probability proportional to its length, a
    point uniformly along it, then a lateral offset [m] and heading error [rad] uniformly within the
    bounds. ``use_map_start``: use the map's ``start_pose`` / ``start_tile`` when it has one.
    """

    lateral: float = 0.04
    heading: float = 0.35
    use_map_start: bool = True


def _start_segments(m: Map, net: LaneNetwork) -> list:
    """Lanes an episode may start on: plain road tiles, never a lane that leaves the map before the next tile."""
    segs = [s for s in net.segments
            if m.tile(*s.tile).kind in ("straight", "curve_left", "curve_right") and net.successors(s.index)
            ] or list(net.segments)
    if not segs:
        raise ValueError(f"map {m.name!r} has no lanes to start on")
    return segs


def _clear_of_objects(x: float, y: float, colliders: np.ndarray) -> bool:
    """Whether a robot at (x, y) [m] is ``_START_CLEARANCE`` beyond every map object's collision margin."""
    return all(footprint_distance(x, y, c) >= c[CF_MARGIN] + _START_CLEARANCE for c in colliders)


def _draw_start(m: Map, segs: list, start: StartDistribution, rng: np.random.Generator,
                colliders: np.ndarray) -> tuple[float, float, float]:
    if start.use_map_start and m.start_pose is not None:
        return m.start_pose
    if start.use_map_start and m.start_tile is not None:
        segs = [s for s in segs if s.tile == m.start_tile] or segs
    lengths = np.array([s.length for s in segs])
    for _ in range(_START_TRIES):  # like gym-duckietown, never start on (or right at) a map object
        seg = segs[int(rng.choice(len(segs), p=lengths / lengths.sum()))]
        s = float(rng.uniform(0.1, 0.9)) * seg.length
        r = float(rng.uniform(-start.lateral, start.lateral))
        dh = float(rng.uniform(-start.heading, start.heading))
        x, y = seg.position(s, r)
        if _clear_of_objects(x, y, colliders):
            break
    return x, y, math.remainder(seg.heading_at(s) + dh, 2 * math.pi)


def start_pose(m: Map, seed: int, start: StartDistribution | None = None,
               net: LaneNetwork | None = None) -> tuple[float, float, float]:
    """The start (x [m], y [m], θ [rad]) that ``Simulator.reset`` draws for ``seed`` on ``m``, for a caller
    that must send it (a robot node is told where its robot stands, as AIDO's ``spawn_robot`` requires)."""
    net = net or LaneNetwork(m)
    return _draw_start(m, _start_segments(m, net), start or StartDistribution(), np.random.default_rng(seed),
                       pack_objects(m.objects).colliders)


class Simulator:
    """N robots on one map. Arrays are views the caller may read (not write) between steps:

    - ``state`` (N, ST.N): x [m], y [m], θ [rad], v [m/s], ω [rad/s], wheel angles [rad], off-road flag.
    - ``lane`` (N, LP.N): lane pose rows (see ``lane_pose.LANE_POSE_FIELDS``), updated every frame.
    - ``frame_index`` (N,): frames since each robot's reset.
    - ``collided`` (N,) bool: the robot has hit a map object this episode (see :attr:`collided`);
      ``hit_kind`` (N,) what it hit first (index into ``worlds.HIT_KINDS``).

    ``npcs`` (one ``Traffic`` for every robot, or one per robot) gives each robot's episode its own NPC
    robots and pedestrians (``proxybench.domain.worlds``). The NPC robots are rows N.. of the internal
    arrays (``npc_state``, ``npc_lane``), stepped by the same physics call; :meth:`step` takes their
    wheel commands, :meth:`reset` of robot i places world i's NPCs again.
    """

    def __init__(
        self,
        map_: Map | str,
        params: DomainParams | Sequence[DomainParams] | None = None,
        n: int | None = None,
        *,
        render: bool = True,
        start: StartDistribution | None = None,
        npcs: Traffic | Sequence[Traffic] | None = None,
        shared: bool = False,
        roof_tags: Sequence[int] | None = None,
    ):
        self.map = load_map(map_) if isinstance(map_, str) else map_
        self.net = LaneNetwork(self.map)
        self.arrays = self.net.arrays
        if params is None or isinstance(params, DomainParams):
            plist = [params or DomainParams()] * (n or 1)
        else:
            plist = list(params)
            if n is not None and n != len(plist):
                raise ValueError(f"n={n} but {len(plist)} parameter sets were given")
        if not plist:
            raise ValueError("a simulator needs at least one robot")
        self.n = len(plist)
        self.params: list[DomainParams] = list(plist)
        self.start = start or StartDistribution()
        first = plist[0]
        self.substeps = first.substeps
        self.frame_dt = 1.0 / first.frame_rate
        self.objects = pack_objects(self.map.objects)
        traffic = [npcs or Traffic()] * self.n if npcs is None or isinstance(npcs, Traffic) else list(npcs)
        #: a shared world (a lab's robots, :mod:`proxybench.runner.lab_world`): the egos see and can hit each other,
        #: each wearing roof tag ``roof_tags[i]`` (default 400 + i); otherwise each ego is alone in a world of its own
        self.shared = bool(shared)
        tags = list(roof_tags) if roof_tags is not None else [ROOF_TAG_BASE + i for i in range(self.n)]
        self.roof_tags = tuple(tags) if self.shared else (ROOF_TAG_BASE,) * self.n
        self.worlds = Worlds(self.net, self.objects, traffic, self.n, tags if self.shared else None)
        #: shared world: the robot each ego first touched this episode (-1: none) and whether it was at fault
        #: (moving towards the other: ``worlds.robot_contacts``); only an ego at fault is ``collided``
        self.contact = np.full(self.n, -1, dtype=np.int64)
        self.contact_fault = np.zeros(self.n, dtype=np.bool_)
        rows = self.worlds.rows  # the N egos, then the NPC robots; public arrays are views of the egos' rows
        self._state = np.zeros((rows, ST.N))
        self.dyn = np.zeros((rows, len(pack_dynamics(first))))
        self._commands = np.zeros((rows, 2))
        self.tick = np.zeros(rows, dtype=np.int64)
        self.applied_tick = np.zeros(rows, dtype=np.int64)
        self._seeds = np.zeros(rows, dtype=np.uint64)
        self._frame_index = np.zeros(rows, dtype=np.int64)
        self._lane = np.zeros((rows, LP.N))
        self.blur_ticks = np.zeros(rows)
        self.blur_count = np.ones(rows, dtype=np.int64)
        self._alloc_history(plist)
        self._collided = np.zeros(rows, dtype=np.bool_)
        self._hit = np.zeros(rows, dtype=np.int8)
        n = self.n
        self.state, self.commands, self.seeds, self.frame_index = (
            self._state[:n], self._commands[:n], self._seeds[:n], self._frame_index[:n])
        self.lane, self.collided, self.hit_kind = self._lane[:n], self._collided[:n], self._hit[:n]
        self.npc_state, self.npc_lane = self._state[n:], self._lane[n:]
        self._trace = np.zeros((rows, first.substeps, len(TRACE_FIELDS)))
        self.npc_frames: np.ndarray | None = None  # (K, H, W, 3) NPC camera frames of the last render, if asked
        self.renderer = Renderer(self.arrays, self._row_params(), self.objects) if render else None
        self._start_segments = _start_segments(self.map, self.net)
        self.routes = RouteTracker(self.net, rows)  # exits chosen at intersections (domain.routes)
        for i, p in enumerate(plist):
            self.set_params(i, p)
            self.reset(i, seed=i)

    # -- configuration ---------------------------------------------------------------------------

    def _alloc_history(self, plist: Sequence[DomainParams]) -> None:
        depth = max(p.delay_ticks + p.jitter_ticks for p in plist) + 2
        blur = max(math.ceil(p.blur_time * p.physics_rate) for p in plist) + 3
        rows = self.worlds.rows
        self.cmd_hist = np.zeros((rows, depth, 2))
        self.pose_hist = np.zeros((rows, blur, 3))
        k = max(p.blur_samples if p.blur_time > 0 else 1 for p in plist)
        self.sub_poses = np.zeros((rows, k, 3))

    def _row_params(self) -> list[DomainParams]:
        """θ of every row: an NPC robot lives in its ego's domain."""
        return [self.params[w] for w in self.worlds.row_world]

    def _rows_of(self, i: int) -> list[int]:
        """Rows of world i: its ego, then its NPC robots."""
        return [i, *range(self.worlds.robot_lo[i], self.worlds.robot_hi[i])]

    def set_params(self, i: int, p: DomainParams) -> None:
        """Use θ = ``p`` for robot ``i``; takes effect now (call :meth:`reset` for a clean episode)."""
        first = self.params[0] if i != 0 else p
        for name in STRUCTURAL_FIELDS:
            if getattr(p, name) != getattr(first, name) and self.n > 1:
                raise ValueError(
                    f"robot {i}: {name}={getattr(p, name)} differs from the batch's {getattr(first, name)}"
                )
        self.params[i] = p
        rows = self._rows_of(i)
        self.dyn[rows] = pack_dynamics(p)
        self.worlds.set_params(i, p)
        need_depth = p.delay_ticks + p.jitter_ticks + 2
        need_blur = math.ceil(p.blur_time * p.physics_rate) + 3
        need_k = p.blur_samples if p.blur_time > 0 else 1
        if (need_depth > self.cmd_hist.shape[1] or need_blur > self.pose_hist.shape[1]
                or need_k > self.sub_poses.shape[1]):
            self._grow(need_depth, need_blur, need_k)
        self.blur_ticks[rows] = p.blur_time * p.physics_rate
        self.blur_count[rows] = need_k
        if self.renderer is not None:
            for r in rows:
                self.renderer.set_params(r, p)

    def _grow(self, depth: int, blur: int, k: int) -> None:
        """Larger history rings; histories restart (only call between episodes)."""
        rows = self.worlds.rows
        self.cmd_hist = np.zeros((rows, max(depth, self.cmd_hist.shape[1]), 2))
        self.pose_hist = np.zeros((rows, max(blur, self.pose_hist.shape[1]), 3))
        self.sub_poses = np.zeros((rows, max(k, self.sub_poses.shape[1]), 3))
        self.pose_hist[:] = self._state[:, None, :3]

    # -- episodes --------------------------------------------------------------------------------

    def sample_start(self, rng: np.random.Generator) -> tuple[float, float, float]:
        """A start pose (x, y, θ) from the start distribution (or the map's own start)."""
        return _draw_start(self.map, self._start_segments, self.start, rng, self.objects.colliders)

    def reset(self, i: int, seed: int, pose: tuple[float, float, float] | None = None,
              route: Sequence[str] | None = None) -> None:
        """Start a new episode for robot ``i``: at ``pose`` if given, else drawn from ``seed``.

        ``route``: turns (left / straight / right) at the intersections it comes to, in order; where it
        runs out, exits are drawn from ``seed`` (see ``proxybench.domain.routes``).
        """
        rng = np.random.default_rng(seed)
        x, y, th = pose if pose is not None else self.sample_start(rng)
        self._place(i, (x, y, th), seed, seed, route)
        self._update_lane(np.array([i]))
        self._reset_npcs(i, seed)
        self._start_collisions(i)

    def _reset_npcs(self, i: int, seed: int) -> None:
        """Place world i's NPC robots for the episode of ``seed``, from their own random stream."""
        w = self.worlds
        rows = list(range(w.robot_lo[i], w.robot_hi[i]))
        if not rows:
            return
        ego = (float(self.state[i, ST.X]), float(self.state[i, ST.Y]), float(self.state[i, ST.THETA]))
        lane = (int(self.lane[i, LP.SEGMENT]) if self.lane[i, LP.VALID] > 0.5 else -1, float(self.lane[i, LP.ALONG]))
        peds = w.peds.pts[w.ped_lo[i]: w.ped_hi[i], 0]  # where the world's pedestrians stand at t = 0
        occupied = [ego[:2], *self.objects.colliders[:, :2], *w.extra_cols[w.extra_lo[i]: w.extra_hi[i], :2], *peds]
        for j, r in enumerate(rows):
            rng = np.random.default_rng(np.random.SeedSequence([seed & _MASK64, _NPC_STREAM, j]))
            x, y, th = npc_start(self.net, w.robot_specs[r - self.n], rng, ego, lane, np.array(occupied))
            occupied.append((x, y))
            self._place(r, (x, y, th), int(rng.integers(2**62)), int(rng.integers(2**62)), None)  # in this order
        self._update_lane(np.array(rows))

    def _place(self, r: int, pose: tuple[float, float, float], seed: int, route_seed: int,
               route: Sequence[str] | None) -> None:
        """Row ``r`` (an ego or an NPC robot) standing still at ``pose`` at tick 0, its histories cleared, its
        noise stream from ``seed`` and its exits from ``route`` and ``route_seed``; its lane pose is the caller's."""
        x, y, th = pose
        self._state[r] = 0.0
        self._state[r, ST.X], self._state[r, ST.Y], self._state[r, ST.THETA] = x, y, math.remainder(th, 2 * math.pi)
        self._commands[r] = 0.0
        self.cmd_hist[r] = 0.0
        self.tick[r] = 0
        self.applied_tick[r] = -1
        self.pose_hist[r] = self._state[r, :3]
        self._seeds[r] = np.uint64(episode_seed(seed))
        self._frame_index[r] = 0
        self.routes.reset(r, route_seed, route)
        a = self.arrays
        self._state[r, ST.OFF_ROAD] = 0.0 if point_on_road(x, y, a.tile_kind, a.curve_corner, a.tile_size) else 1.0

    def _start_collisions(self, i: int) -> None:
        """``collided`` of world i's robots where they stand at the start of its episode."""
        rows = self._rows_of(i)
        self._collided[rows] = False
        self._hit[rows] = 0
        self.contact[i], self.contact_fault[i] = -1, False
        points = self._state[:, None, :2].copy()
        if self.objects.colliders.shape[0]:
            flag = np.zeros(len(rows), dtype=np.bool_)
            collision_check(points[rows], self.objects.colliders, flag)
            self._collided[rows] = flag
            self._hit[rows] = flag
        if self.worlds.active:
            self.worlds.collide(points, self.tick - 1, self.params[0].physics_dt, self._collided, self._hit, i)

    # -- stepping --------------------------------------------------------------------------------

    def step(self, commands: np.ndarray, trace: np.ndarray | None = None, npc_commands: np.ndarray | None = None,
             ) -> None:
        """Hold PWM ``commands`` (N, 2) (left, right) for one camera frame of ``substeps`` physics ticks.

        ``trace`` (N, substeps, len(TRACE_FIELDS)), if given, receives every tick's state (physics-rate
        trajectories). ``npc_commands`` (K, 2): PWM of the NPC robots (default none: they stand still),
        multiplied by each one's ``speed_scale`` and its world's ``npc_speed_scale``; a stopped NPC robot
        (:attr:`npc_stopped`) gets none.
        """
        c = np.asarray(commands, dtype=np.float64).reshape(self.n, 2)
        if not np.all(np.isfinite(c)):
            raise ValueError("wheel commands must be finite numbers")
        np.clip(c, -1.0, 1.0, out=self.commands)
        w = self.worlds
        if w.k:
            nc = np.zeros((w.k, 2)) if npc_commands is None else np.asarray(npc_commands, dtype=np.float64)
            if nc.shape != (w.k, 2) or not np.all(np.isfinite(nc)):
                raise ValueError(f"NPC wheel commands must be ({w.k}, 2) finite numbers")
            scale = np.where(self.npc_stopped, 0.0, w.robot_scale * w.speed_scale[w.robot_world])
            np.clip(nc * scale[:, None], -1.0, 1.0, out=self._commands[self.n:])
        a = self.arrays
        dynamic = w.active
        check = self.objects.colliders.shape[0] > 0 or dynamic
        own = trace
        if w.k or (trace is None and check):
            trace = self._trace  # every row; collisions are checked at every physics tick, from the trace
        tick0 = self.tick.copy() if dynamic else None
        physics_ticks(
            self._state, self.dyn, self._commands, self.cmd_hist, self.applied_tick, self.tick, self._seeds,
            self.substeps, self.pose_hist, a.tile_kind, a.curve_corner, a.tile_size,
            _NO_TRACE if trace is None else trace,
        )
        if check:
            if self.objects.colliders.shape[0]:
                before = self._collided.copy()
                collision_check(trace, self.objects.colliders, self._collided)
                self._hit[self._collided & ~before] = 1
            if dynamic:
                w.collide(trace, tick0, self.params[0].physics_dt, self._collided, self._hit)
            if self.shared and self.n > 1:
                self._robot_contacts(trace)
        if own is not None and own is not trace:
            own[:] = trace[: self.n]
        self._frame_index += 1
        self._update_lane(None)

    def _robot_contacts(self, trace: np.ndarray) -> None:
        """A shared world's robot-to-robot contacts of this frame: the one at fault is ``collided`` (with a robot)."""
        before = self.contact.copy()
        robot_contacts(trace, self.n, self.contact, self.contact_fault)
        new = (before < 0) & (self.contact >= 0) & self.contact_fault & ~self.collided
        self.collided[new] = True
        self.hit_kind[new] = HIT_KINDS.index("robot")

    def _update_lane(self, idx: np.ndarray | None) -> None:
        a = self.arrays
        poses = np.ascontiguousarray(self._state[:, :3] if idx is None else self._state[idx, :3])
        out = self._lane if idx is None else np.empty((poses.shape[0], LP.N))  # all rows: in place
        half = 0.5 * (self.dyn[:, _WHEEL_DISTANCE] if idx is None else self.dyn[idx, _WHEEL_DISTANCE])
        _lane_poses(
            poses, half, a.seg_kind, a.seg_f, a.tile_segs, a.tile_kind, a.curve_corner, a.tile_size,
            a.lane_half_width, out,
        )
        if self.routes.active:  # maps with intersections: pin the lane pose to each robot's chosen exit
            which = np.arange(self.worlds.rows) if idx is None else idx
            self.routes.update(which, poses, half, out, self._frame_index[which] * self.frame_dt)
        if idx is not None:
            self._lane[idx] = out

    def enable_rendering(self) -> None:
        """Build the renderer now if this simulator was created with ``render=False``."""
        if self.renderer is None:
            self.renderer = Renderer(self.arrays, self._row_params(), self.objects)

    def render(self, out: np.ndarray | None = None, active: np.ndarray | None = None,
               npc_active: np.ndarray | None = None) -> np.ndarray:
        """Camera frames (N, H, W, 3) uint8 of the current poses, motion-blurred over ``blur_time``.

        ``active`` (N,) bool: render only these robots; the frames of the others are undefined.
        ``npc_active`` (K,) bool: also render these NPC robots' cameras, into :attr:`npc_frames` (K, H, W, 3).
        Each robot sees the map's objects and its own world's; moving ones are drawn where they are now
        (not motion-blurred).
        """
        if self.renderer is None:
            raise RuntimeError("this simulator was built with render=False")
        blur_poses(self.pose_hist, self.tick, self._state, self.dyn, self.blur_ticks, self.blur_count, self.sub_poses)
        n = self.n
        counts = self.blur_count if active is None else np.where(active, self.blur_count[:n], 0)
        npcs = npc_active is not None and bool(np.any(npc_active))
        if self.worlds.k:
            counts = np.concatenate([counts[:n], np.where(npc_active, self.blur_count[n:], 0) if npcs
                                     else np.zeros(self.worlds.k, dtype=np.int64)])
        if out is None:
            r = self.renderer
            out = np.empty((self.worlds.rows if npcs else n, r.height, r.width, 3), dtype=np.uint8)
        moving = ranges = None
        if self.worlds.active:
            moving = self.worlds.moving_prims(self._state, self.tick, self.params[0].physics_dt)
            ranges = self.worlds.ranges
        frames = self.renderer.render(self.sub_poses, self._seeds, self._frame_index, out, counts, moving, ranges)
        self.npc_frames = frames[n:] if npcs else None
        return frames[:n]

    # -- NPC robots and worlds -------------------------------------------------------------------

    @property
    def npc_world(self) -> np.ndarray:
        """(K,) the world (ego index) of each NPC robot."""
        return self.worlds.robot_world

    @property
    def npc_stopped(self) -> np.ndarray:
        """(K,) bool: the NPC robot has left the road or touched something; it gets no more wheel commands."""
        return self._collided[self.n:] | (self._state[self.n:, ST.OFF_ROAD] > 0.5)

    @property
    def npc_hit_kind(self) -> np.ndarray:
        """(K,) what each NPC robot hit (index into ``worlds.HIT_KINDS``; 0: nothing)."""
        return self._hit[self.n:]

    def world_view(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """World i beyond the map: (its extra duckies and pedestrians as primitives (P, PF), its NPC robots'
        poses (M, 3)), e.g. for top-down views."""
        w = self.worlds
        prims = w.objects_of(i, self._state, self.tick, self.params[0].physics_dt)
        return prims, self._state[w.robot_lo[i]: w.robot_hi[i], :3].copy()

    @property
    def off_road(self) -> np.ndarray:
        """(N,) bool: the robot centre has left the drivable area this episode."""
        return self.state[:, ST.OFF_ROAD] > 0.5

    # ``collided`` (N,) bool is a plain attribute: True once the robot has touched a map object, or an extra
    # duckie, pedestrian or NPC robot of its own world, this episode (sticky until reset, like ``off_road``;
    # ``hit_kind`` says which). Rule (AIDO): the robot centre comes within 0.10 m of a duckie-like object's
    # footprint, or within 0.15 m of a robot-like object's (or robot's) centre; checked at every physics
    # tick (``objects.collision_check``, ``worlds.world_collisions``). The robot keeps moving; ending the
    # episode is the caller's.

    @property
    def time(self) -> np.ndarray:
        """(N,) seconds since each robot's reset."""
        return self.frame_index * self.frame_dt
