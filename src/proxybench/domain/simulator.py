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

from proxybench.domain.dynamics import DYN_FIELDS, ST, TRACE_FIELDS, blur_poses, pack_dynamics, physics_ticks
from proxybench.domain.lane_pose import LP, lane_pose_into, point_on_road
from proxybench.domain.lanes import LaneNetwork
from proxybench.domain.maps import Map, load_map
from proxybench.domain.objects import collision_check, pack_objects
from proxybench.domain.params import STRUCTURAL_FIELDS, DomainParams
from proxybench.domain.renderer import Renderer

__all__ = ["Simulator", "StartDistribution", "episode_seed"]

_MASK64 = (1 << 64) - 1
_WHEEL_DISTANCE = DYN_FIELDS.index("wheel_distance")
_NO_TRACE = np.zeros((0, 0, len(TRACE_FIELDS)))


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


class Simulator:
    """N robots on one map. Arrays are views the caller may read (not write) between steps:

    - ``state`` (N, ST.N): x [m], y [m], θ [rad], v [m/s], ω [rad/s], wheel angles [rad], off-road flag.
    - ``lane`` (N, LP.N): lane pose rows (see ``lane_pose.LANE_POSE_FIELDS``), updated every frame.
    - ``frame_index`` (N,): frames since each robot's reset.
    - ``collided`` (N,) bool: the robot has hit a map object this episode (see :attr:`collided`).
    """

    def __init__(
        self,
        map_: Map | str,
        params: DomainParams | Sequence[DomainParams] | None = None,
        n: int | None = None,
        *,
        render: bool = True,
        start: StartDistribution | None = None,
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
        self.state = np.zeros((self.n, ST.N))
        self.dyn = np.zeros((self.n, len(pack_dynamics(first))))
        self.commands = np.zeros((self.n, 2))
        self.tick = np.zeros(self.n, dtype=np.int64)
        self.applied_tick = np.zeros(self.n, dtype=np.int64)
        self.seeds = np.zeros(self.n, dtype=np.uint64)
        self.frame_index = np.zeros(self.n, dtype=np.int64)
        self.lane = np.zeros((self.n, LP.N))
        self.blur_ticks = np.zeros(self.n)
        self.blur_count = np.ones(self.n, dtype=np.int64)
        self._alloc_history(plist)
        self.objects = pack_objects(self.map.objects)
        self.collided = np.zeros(self.n, dtype=np.bool_)
        self._trace = np.zeros((self.n, first.substeps, len(TRACE_FIELDS)))
        self.renderer = Renderer(self.arrays, plist, self.objects) if render else None
        # start on plain road tiles, never on a lane that leaves the map before the next tile
        self._start_segments = [
            s for s in self.net.segments
            if self.map.tile(*s.tile).kind in ("straight", "curve_left", "curve_right") and self.net.successors(s.index)
        ] or list(self.net.segments)
        if not self._start_segments:
            raise ValueError(f"map {self.map.name!r} has no lanes to start on")
        for i, p in enumerate(plist):
            self.set_params(i, p)
            self.reset(i, seed=i)

    # -- configuration ---------------------------------------------------------------------------

    def _alloc_history(self, plist: Sequence[DomainParams]) -> None:
        depth = max(p.delay_ticks + p.jitter_ticks for p in plist) + 2
        blur = max(math.ceil(p.blur_time * p.physics_rate) for p in plist) + 3
        self.cmd_hist = np.zeros((self.n, depth, 2))
        self.pose_hist = np.zeros((self.n, blur, 3))
        k = max(p.blur_samples if p.blur_time > 0 else 1 for p in plist)
        self.sub_poses = np.zeros((self.n, k, 3))

    def set_params(self, i: int, p: DomainParams) -> None:
        """Use θ = ``p`` for robot ``i``; takes effect now (call :meth:`reset` for a clean episode)."""
        first = self.params[0] if i != 0 else p
        for name in STRUCTURAL_FIELDS:
            if getattr(p, name) != getattr(first, name) and self.n > 1:
                raise ValueError(
                    f"robot {i}: {name}={getattr(p, name)} differs from the batch's {getattr(first, name)}"
                )
        self.params[i] = p
        self.dyn[i] = pack_dynamics(p)
        need_depth = p.delay_ticks + p.jitter_ticks + 2
        need_blur = math.ceil(p.blur_time * p.physics_rate) + 3
        need_k = p.blur_samples if p.blur_time > 0 else 1
        if (need_depth > self.cmd_hist.shape[1] or need_blur > self.pose_hist.shape[1]
                or need_k > self.sub_poses.shape[1]):
            self._grow(need_depth, need_blur, need_k)
        self.blur_ticks[i] = p.blur_time * p.physics_rate
        self.blur_count[i] = need_k
        if self.renderer is not None:
            self.renderer.set_params(i, p)

    def _grow(self, depth: int, blur: int, k: int) -> None:
        """Larger history rings; histories restart (only call between episodes)."""
        self.cmd_hist = np.zeros((self.n, max(depth, self.cmd_hist.shape[1]), 2))
        self.pose_hist = np.zeros((self.n, max(blur, self.pose_hist.shape[1]), 3))
        self.sub_poses = np.zeros((self.n, max(k, self.sub_poses.shape[1]), 3))
        self.pose_hist[:] = self.state[:, None, :3]

    # -- episodes --------------------------------------------------------------------------------

    def sample_start(self, rng: np.random.Generator) -> tuple[float, float, float]:
        """A start pose (x, y, θ) from the start distribution (or the map's own start)."""
        if self.start.use_map_start and self.map.start_pose is not None:
            return self.map.start_pose
        segs = self._start_segments
        if self.start.use_map_start and self.map.start_tile is not None:
            segs = [s for s in segs if s.tile == self.map.start_tile] or segs
        lengths = np.array([s.length for s in segs])
        seg = segs[int(rng.choice(len(segs), p=lengths / lengths.sum()))]
        s = float(rng.uniform(0.1, 0.9)) * seg.length
        r = float(rng.uniform(-self.start.lateral, self.start.lateral))
        dh = float(rng.uniform(-self.start.heading, self.start.heading))
        x, y = seg.position(s, r)
        return x, y, math.remainder(seg.heading_at(s) + dh, 2 * math.pi)

    def reset(self, i: int, seed: int, pose: tuple[float, float, float] | None = None) -> None:
        """Start a new episode for robot ``i``: at ``pose`` if given, else drawn from ``seed``."""
        rng = np.random.default_rng(seed)
        x, y, th = pose if pose is not None else self.sample_start(rng)
        self.state[i] = 0.0
        self.state[i, ST.X], self.state[i, ST.Y], self.state[i, ST.THETA] = x, y, math.remainder(th, 2 * math.pi)
        self.commands[i] = 0.0
        self.cmd_hist[i] = 0.0
        self.tick[i] = 0
        self.applied_tick[i] = -1
        self.pose_hist[i] = self.state[i, :3]
        self.seeds[i] = np.uint64(episode_seed(seed))
        self.frame_index[i] = 0
        self._update_lane(np.array([i]))
        a = self.arrays
        self.state[i, ST.OFF_ROAD] = 0.0 if point_on_road(x, y, a.tile_kind, a.curve_corner, a.tile_size) else 1.0
        self.collided[i] = False
        if self.objects.colliders.shape[0]:
            flag = np.zeros(1, dtype=np.bool_)
            collision_check(self.state[i : i + 1, None, :2].copy(), self.objects.colliders, flag)
            self.collided[i] = flag[0]

    # -- stepping --------------------------------------------------------------------------------

    def step(self, commands: np.ndarray, trace: np.ndarray | None = None) -> None:
        """Hold PWM ``commands`` (N, 2) (left, right) for one camera frame of ``substeps`` physics ticks.

        ``trace`` (N, substeps, len(TRACE_FIELDS)), if given, receives every tick's state (physics-rate
        trajectories).
        """
        c = np.asarray(commands, dtype=np.float64).reshape(self.n, 2)
        if not np.all(np.isfinite(c)):
            raise ValueError("wheel commands must be finite numbers")
        np.clip(c, -1.0, 1.0, out=self.commands)
        a = self.arrays
        check = self.objects.colliders.shape[0] > 0
        if trace is None and check:
            trace = self._trace  # collisions are checked at every physics tick, from the trace
        physics_ticks(
            self.state, self.dyn, self.commands, self.cmd_hist, self.applied_tick, self.tick, self.seeds,
            self.substeps, self.pose_hist, a.tile_kind, a.curve_corner, a.tile_size,
            _NO_TRACE if trace is None else trace,
        )
        if check:
            collision_check(trace, self.objects.colliders, self.collided)
        self.frame_index += 1
        self._update_lane(None)

    def _update_lane(self, idx: np.ndarray | None) -> None:
        a = self.arrays
        poses = np.ascontiguousarray(self.state[:, :3] if idx is None else self.state[idx, :3])
        out = np.empty((poses.shape[0], LP.N))
        half = 0.5 * (self.dyn[:, _WHEEL_DISTANCE] if idx is None else self.dyn[idx, _WHEEL_DISTANCE])
        _lane_poses(
            poses, half, a.seg_kind, a.seg_f, a.tile_segs, a.tile_kind, a.curve_corner, a.tile_size,
            a.lane_half_width, out,
        )
        if idx is None:
            self.lane[:] = out
        else:
            self.lane[idx] = out

    def enable_rendering(self) -> None:
        """Build the renderer now if this simulator was created with ``render=False``."""
        if self.renderer is None:
            self.renderer = Renderer(self.arrays, self.params, self.objects)

    def render(self, out: np.ndarray | None = None, active: np.ndarray | None = None) -> np.ndarray:
        """Camera frames (N, H, W, 3) uint8 of the current poses, motion-blurred over ``blur_time``.

        ``active`` (N,) bool: render only these robots; the frames of the others are undefined.
        """
        if self.renderer is None:
            raise RuntimeError("this simulator was built with render=False")
        blur_poses(self.pose_hist, self.tick, self.state, self.dyn, self.blur_ticks, self.blur_count, self.sub_poses)
        counts = self.blur_count if active is None else np.where(active, self.blur_count, 0)
        return self.renderer.render(self.sub_poses, self.seeds, self.frame_index, out, counts)

    @property
    def off_road(self) -> np.ndarray:
        """(N,) bool: the robot centre has left the drivable area this episode."""
        return self.state[:, ST.OFF_ROAD] > 0.5

    # ``collided`` (N,) bool is a plain attribute: True once the robot has touched a map object this
    # episode (sticky until reset, like ``off_road``). Rule (AIDO): the robot centre comes within 0.10 m of
    # a duckie-like object's footprint, or within 0.15 m of a robot-like object's centre; checked at every
    # physics tick (``objects.collision_check``). The robot keeps moving; ending the episode is the caller's.

    @property
    def time(self) -> np.ndarray:
        """(N,) seconds since each robot's reset."""
        return self.frame_index * self.frame_dt
