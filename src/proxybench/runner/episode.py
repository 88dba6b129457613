"""Episodes in the simulator: :class:`SimPlant` (the batched simulator as a plant of the episode engine) and
the in-process entry points :func:`run_episode` / :func:`run_episodes` (agents on a simulator, recorded at
the physics rate).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.domain.dynamics import ST, TRACE_FIELDS, wheel_ticks
from proxybench.domain.episode_end import end_event, ended
from proxybench.domain.kinds import DomainKind
from proxybench.domain.lane_pose import LanePose
from proxybench.domain.maps import Map
from proxybench.domain.params import DomainParams
from proxybench.domain.range_sensor import front_range
from proxybench.domain.simulator import Simulator
from proxybench.runner.npcs import NpcDrivers
from proxybench.runner.rollout import AgentPolicy, FrameHook, PrivilegedAgentError, rollout
from proxybench.tasks.trajectory import Event, Trajectory

__all__ = ["PrivilegedAgentError", "SimPlant", "play", "run_episode", "run_episodes", "sim_plant"]

_NO_ROBOTS = np.zeros((0, 3))


class SimPlant:
    """A batched :class:`Simulator` as a plant: robot i of ``sim`` is robot i of the rollout.

    Physics and rendering advance all robots in one compiled call per frame; robot i meets only the NPCs
    of its own world, so a batch gives the same trajectories as N single runs. The simulator's NPC robots
    are driven by the zoo agents their specs name (``runner.npcs``). ``image_filter`` transforms each
    camera frame before a driver sees it (e.g. the JPEG round trip, so that in-process and remote agents
    see the same pixels); without one, :meth:`frames` is the renderer's (N, H, W, 3) array.

    ``trace=False``: no physics-rate record, so no trajectories: a continuing stream whose robots restart apart
    (:meth:`restart`, under :class:`~proxybench.runner.autoreset.AutoResetPlant`), whose frames the engine counts
    past any episode's length.
    """

    def __init__(self, sim: Simulator, image_filter: Callable[[np.ndarray], np.ndarray] | None = None, *,
                 trace: bool = True):
        self.sim = sim
        self.n = sim.n
        self.map = sim.map
        self.image_filter = image_filter
        self.traced = trace
        self.drivers: NpcDrivers | None = None

    @property
    def frame_rate(self) -> float:
        """[Hz] camera frames (decisions) per second."""
        return 1.0 / self.sim.frame_dt

    def begin(self, seeds: Sequence[int], poses: Sequence[Any], routes: Sequence[Any], seconds: float,
              camera: bool, privileged: Sequence[bool]) -> int:
        sim, n = self.sim, self.n
        steps = max(1, round(seconds / sim.frame_dt))
        self.camera = camera
        if self.traced:
            self.trace = np.zeros((n, steps, sim.substeps, len(TRACE_FIELDS)))
            self.lanes = np.full((2, n, steps), -1, dtype=np.int64)  # per frame: pinned lane, lane chosen ahead
        for i in range(n):
            sim.reset(i, int(seeds[i]), poses[i], routes[i])
        self.start = sim.state.copy()
        self.drivers = NpcDrivers(sim, self.image_filter) if sim.worlds.k else None
        if self.drivers is not None:
            self.drivers.reset(seeds)
        return steps

    def set_params(self, i: int, params: DomainParams) -> None:
        """θ of robot ``i``'s next episode (a domain family's draw), before :meth:`begin` or :meth:`restart`."""
        self.sim.set_params(i, params)

    def restart(self, i: int, seed: int, pose: tuple[float, float, float] | None = None) -> None:
        """Start robot ``i``'s next episode now, from ``seed`` (and ``pose``), while the others go on: for a
        plant built with ``trace=False`` and no NPC robots (whose drivers restart with every world at once)."""
        if self.traced or self.drivers is not None:
            raise ValueError("only a SimPlant(trace=False) without NPC robots restarts one robot mid-stream")
        self.sim.reset(i, seed, pose)

    def frames(self, alive: np.ndarray) -> Any:
        npc_cams = self.drivers.wants_camera(alive) if self.drivers is not None else None
        if not (self.camera or npc_cams is not None):
            return None
        frames = self.sim.render(active=alive if self.camera else np.zeros(self.n, dtype=bool), npc_active=npc_cams)
        if not self.camera:
            return None
        if self.image_filter is None:
            return frames
        return [self.image_filter(f) if alive[i] else None for i, f in enumerate(frames)]

    def observation(self, i: int, image: np.ndarray | None, privileged: bool) -> Observation:
        sim = self.sim
        s = sim.state[i]
        res = sim.params[i].encoder_resolution
        ticks = wheel_ticks(s[[ST.WHEEL_L, ST.WHEEL_R]], res)
        lp = LanePose.from_row(sim.lane[i]) if privileged else None
        route = sim.routes.info(i, sim.lane[i]) if privileged else None
        pose = (float(s[ST.X]), float(s[ST.Y]), float(s[ST.THETA])) if privileged else None
        return Observation(image, float(sim.time[i]), (float(ticks[0] * res), float(ticks[1] * res)), res, lp, route,
                           pose, lambda: self.front_range(i))

    def front_range(self, i: int) -> float | None:
        """Robot ``i``'s front time-of-flight range [m] now (None: nothing within range)."""
        sim = self.sim
        s = sim.state[i]
        robots = sim.npc_state[sim.npc_world == i, :3] if sim.worlds.k else _NO_ROBOTS
        return front_range(sim.objects.colliders, robots, s[ST.X], s[ST.Y], s[ST.THETA])

    def time(self, i: int) -> float:
        return float(self.sim.time[i])

    def advance(self, commands: np.ndarray, alive: np.ndarray, k: int) -> list[tuple[int, Event, bool]]:
        sim, drivers = self.sim, self.drivers
        trace = None
        if self.traced:
            self.lanes[:, :, k] = sim.routes.pin[: self.n], sim.routes.next[: self.n]  # the egos' rows (NPCs follow)
            trace = self.trace[:, k]
        sim.step(commands, trace, None if drivers is None else drivers.act(alive))
        out = [(w, event, False) for w, event in (drivers.events() if drivers is not None else ()) if alive[w]]
        for i in np.flatnonzero(alive & ended(sim)):
            out.append((int(i), end_event(sim, int(i)), True))
        return out

    def samples(self, i: int, frames: int) -> np.ndarray:
        rows = self.trace[i, :frames].reshape(-1, len(TRACE_FIELDS))
        start = self.start[i]
        out = np.empty((rows.shape[0] + 1, 8))
        out[:, 0] = np.arange(rows.shape[0] + 1) * self.sim.params[i].physics_dt
        out[0, 1:] = start[ST.X], start[ST.Y], start[ST.THETA], start[ST.V], start[ST.OMEGA], 0.0, 0.0
        out[1:, 1:] = rows[:, :7]  # x, y, θ, v, ω, pwm_left, pwm_right
        return out

    def route_lanes(self, i: int, frames: int) -> tuple[Any, np.ndarray, np.ndarray, int, list] | None:
        routes = self.sim.routes
        if not routes.active:
            return None
        return routes.graph, self.lanes[0, i, :frames], self.lanes[1, i, :frames], self.sim.substeps, \
            list(routes.choices[i])

    def meta(self, i: int) -> dict[str, Any]:
        out = {"source": DomainKind.SIMULATION, "params": self.sim.params[i].model_dump(mode="json")}
        traffic = self.sim.worlds.traffic[i]
        if not traffic.empty:
            out["npcs"] = traffic.to_dict()
        return out

    def wheel_distance(self, i: int) -> float:
        return self.sim.params[i].wheel_distance

    def end(self) -> None:
        if self.drivers is not None:
            self.drivers.close()
            self.drivers = None


def sim_plant(map_: Map | str, params: DomainParams | None = None, n: int = 1) -> SimPlant:
    """A plant of ``n`` simulated robots on ``map_`` whose camera frames are what camera agents see (the JPEG round
    trip): for callers that drive the simulator from outside the runner, which build no simulator of their own
    (``proxybench dtps serve``, the contract suites of ``proxybench.testing``)."""
    from proxybench.runner.outcomes import camera_filter

    return SimPlant(Simulator(map_, params or DomainParams(), n=n), camera_filter())


def play(map_: Map | str, params: DomainParams, agent: Agent, seed: int, seconds: float) -> Trajectory:
    """One episode of ``agent`` in a fresh simulator of θ ``params``, camera frames as a node receives them (JPEG),
    e.g. to try an agent out (``proxybench agent check``)."""
    from proxybench.runner.outcomes import camera_filter

    return run_episode(Simulator(map_, params), agent, seed, seconds, camera=not agent.privileged,
                       image_filter=camera_filter())


def run_episode(
    sim: Simulator,
    agent: Agent,
    seed: int,
    seconds: float,
    *,
    pose: tuple[float, float, float] | None = None,
    camera: bool = True,
    allow_privileged: bool = True,
    image_filter: Callable[[np.ndarray], np.ndarray] | None = None,
    on_frame: Callable[[int, np.ndarray | None, Simulator], None] | None = None,
    meta: dict[str, Any] | None = None,
    route: Sequence[str] | None = None,
) -> Trajectory:
    """Drive the single robot of ``sim`` with ``agent`` for ``seconds`` (or until it leaves the road or fails).

    The agent sees a frame every 1/frame_rate s and its command is held until the next frame. The
    trajectory has one sample per physics tick. ``image_filter`` transforms frames before the agent sees
    them (e.g. a JPEG round trip, so that in-process and remote agents see the same pixels);
    ``on_frame(k, image, sim)`` is called after each frame (e.g. to write a video). With
    ``allow_privileged=False`` (camera-only evaluation) a privileged agent is refused. ``route``: the
    turns to take at intersections (see ``Simulator.reset``).
    An exception from the agent ends the episode with termination ``agent_failure``; it is not raised.
    """
    if sim.n != 1:
        raise ValueError(f"run_episode drives a simulator of one robot; this one has {sim.n} (use run_episodes)")
    hook = None if on_frame is None else (lambda k, images, s: on_frame(k, images[0], s))
    return run_episodes(sim, [agent], [seed], seconds, poses=[pose], camera=camera,
                        allow_privileged=allow_privileged, image_filter=image_filter, on_frame=hook,
                        metas=[meta], routes=[route])[0]


def run_episodes(
    sim: Simulator,
    agents: Sequence[Agent],
    seeds: Sequence[int],
    seconds: float,
    *,
    poses: Sequence[tuple[float, float, float] | None] | None = None,
    camera: bool = True,
    allow_privileged: bool = True,
    image_filter: Callable[[np.ndarray], np.ndarray] | None = None,
    on_frame: Callable[[int, list[np.ndarray | None], Simulator], None] | None = None,
    metas: Sequence[dict[str, Any] | None] | None = None,
    routes: Sequence[Sequence[str] | None] | None = None,
    frame_hook: FrameHook | None = None,
) -> list[Trajectory]:
    """Episodes of N agents at once, robot i of ``sim`` driven by ``agents[i]`` from ``seeds[i]``.

    The engine's :func:`~proxybench.runner.rollout.rollout` on a :class:`SimPlant` with an
    :class:`~proxybench.runner.rollout.AgentPolicy`: each robot's episode is exactly what it would be
    alone, so a batch gives the same trajectories as N single runs.

    ``routes[i]``: robot i's turns at intersections. Privileged agents are measured against the exits
    the simulator chose for them (recorded as ``route_segment``); camera agents are free, and their
    route is the exits they took (``proxybench.domain.routes``). ``frame_hook(k, images, alive, plant)``: the
    engine's own frame hook (e.g. recording a lab's watchtowers while the episodes run), after ``on_frame``.
    """
    n = sim.n
    if not (len(agents) == len(seeds) == n):
        raise ValueError(f"{len(agents)} agents and {len(seeds)} seeds for a simulator of {n} robots")
    hook = frame_hook
    if on_frame is not None:
        def hook(k: int, images: Any, alive: np.ndarray, plant: SimPlant) -> None:
            on_frame(k, [None] * n if images is None else list(images), sim)
            if frame_hook is not None:
                frame_hook(k, images, alive, plant)
    return rollout(SimPlant(sim, image_filter), AgentPolicy(agents), seeds, seconds, poses=poses, routes=routes,
                   camera=camera, allow_privileged=allow_privileged, on_frame=hook, metas=metas)
