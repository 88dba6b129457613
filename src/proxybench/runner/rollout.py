"""The episode engine: a plant (where the robots are), a policy (who drives them), one loop, one trajectory.

Every episode proxybench plays goes through :func:`rollout`: the runner's jobs, ``proxybench run``,
robots reached through the robot protocol, learning evaluation and POD. Per camera frame it asks the
plant for what the robots see, the policy for their wheel commands, and the plant to advance one frame
with those commands held; then it applies the ending rule and, at the end, assembles each robot's
physics-rate :class:`~proxybench.tasks.trajectory.Trajectory` the same way for every plant.

The ending rule: a robot's episode ends when its **agent fails** (raises, or returns anything but two
finite numbers: recorded as ``agent_failure`` with the reason, never raised), when the **plant** says it
ended (collision, off the road: ``domain.episode_end`` for the simulator; the robot node reports its own),
or at the **timeout** (the episode's frames are spent). A robot whose episode ended keeps still (zero
commands, no frames) until the others are done.

Plants: :class:`~proxybench.runner.episode.SimPlant` (the batched simulator, with NPC drivers) and
:class:`~proxybench.runner.robot_episode.RobotPlant` (a robot node). Policies: :class:`AgentPolicy`
(one agent per robot, in-process or a protocol node) and :class:`BatchPolicy` (one call for the whole
batch, e.g. a network, or an open-loop command sequence: :class:`OpenLoopPolicy`).
"""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import numpy as np

from proxybench import __version__
from proxybench.agents.base import Agent, Observation
from proxybench.domain.lane_pose import LP
from proxybench.domain.maps import Map
from proxybench.domain.routes import given_route_samples
from proxybench.tasks.trajectory import Event, Termination, Trajectory

__all__ = ["AgentPolicy", "BatchPolicy", "FrameHook", "OpenLoopPolicy", "Plant", "Policy", "PrivilegedAgentError",
           "ResettingPlant", "failure_event", "lane_rows", "rollout", "stream"]

#: a frame hook: ``(k, images, alive, plant)``; ``images`` is what the robots saw (None without cameras),
#: ``alive`` (N,) which robots' episodes are still running
FrameHook = Callable[[int, Any, np.ndarray, "Plant"], None]


class PrivilegedAgentError(ValueError):
    """A privileged agent (one that reads the true lane pose) was given to a camera-only run."""


class Plant(Protocol):
    """Where N robots live and move, one camera frame at a time."""

    n: int
    map: Map
    frame_rate: float  # [Hz] camera frames per second (known once :meth:`begin` returned)

    def begin(self, seeds: Sequence[int], poses: Sequence[Any], routes: Sequence[Any], seconds: float,
              camera: bool, privileged: Sequence[bool]) -> int:
        """Start every robot's episode of ``seconds``; how many frames that is. May raise if the plant cannot."""

    def frames(self, alive: np.ndarray) -> Any:
        """What the running robots see now: (N,) images (arrays, or None where not rendered), or None."""

    def observation(self, i: int, image: np.ndarray | None, privileged: bool) -> Observation:
        """Robot ``i``'s observation at the current frame (with its true lane pose if ``privileged``)."""

    def time(self, i: int) -> float:
        """Robot ``i``'s episode time now [s]."""

    def advance(self, commands: np.ndarray, alive: np.ndarray, k: int) -> list[tuple[int, Event, bool]]:
        """Hold ``commands`` (N, 2) for frame ``k``; the events of running robots as (robot, event, ends it)."""

    def samples(self, i: int, frames: int) -> np.ndarray:
        """(m, 8) rows t, x, y, θ, v, ω, pwm_left, pwm_right of robot ``i``'s first ``frames`` frames."""

    def route_lanes(self, i: int, frames: int) -> tuple[Any, np.ndarray, np.ndarray, int, list] | None:
        """(graph, pins, nexts, substeps, choices): the route the plant chose for robot ``i``, if it did."""

    def meta(self, i: int) -> dict[str, Any]:
        """What the plant says about robot ``i``'s episode: ``source``, ``params``, anything else."""

    def wheel_distance(self, i: int) -> float: ...

    def end(self) -> None:
        """The episodes are over (release per-episode helpers)."""


class Policy(Protocol):
    """Who drives the robots of a plant: wheel PWM (N, 2) per frame from what they see."""

    names: list[str]
    privileged: list[bool]

    def reset(self, seeds: Sequence[int]) -> dict[int, BaseException]:
        """New episodes; the robots whose driver failed to start, with the exception."""

    def act(self, plant: Plant, images: Any, alive: np.ndarray) -> tuple[np.ndarray, dict[int, BaseException]]:
        """Commands (N, 2) of the running robots, and the robots whose driver failed this frame."""


class AgentPolicy:
    """One agent per robot (in-process, or a node behind the protocol): robot i is driven by ``agents[i]``.

    An agent that raises, or answers anything but two finite numbers, fails: its robot's episode ends
    with ``agent_failure`` and the reason; the others go on.
    """

    def __init__(self, agents: Sequence[Agent]):
        self.agents = list(agents)
        self.names = [a.name for a in self.agents]
        self.privileged = [bool(a.privileged) for a in self.agents]
        self.map: Map | None = None

    def set_map(self, map_: Map) -> None:
        """The episode's map, handed to each agent that takes it (``Agent.set_map``) at :meth:`reset`."""
        self.map = map_

    def reset(self, seeds: Sequence[int]) -> dict[int, BaseException]:
        failures = {}
        for i, a in enumerate(self.agents):
            try:
                hook = getattr(a, "set_map", None)  # an agent need not subclass Agent: act() is the contract
                if hook is not None and self.map is not None:
                    hook(self.map)
                a.reset(int(seeds[i]))
            except Exception as exc:  # a failing agent ends its episode, never the run
                failures[i] = exc
        return failures

    def act(self, plant: Plant, images: Any, alive: np.ndarray) -> tuple[np.ndarray, dict[int, BaseException]]:
        out = np.zeros((len(self.agents), 2))
        failures = {}
        for i in np.flatnonzero(alive):
            try:
                obs = plant.observation(i, None if images is None else images[i], self.privileged[i])
                command = np.asarray(self.agents[i].act(obs), dtype=np.float64)
                if command.shape != (2,) or not np.all(np.isfinite(command)):
                    raise ValueError(f"agent returned {command!r}, expected 2 finite wheel PWM values")
                out[i] = command
            except Exception as exc:  # likewise: recorded as the reason the episode ended
                failures[i] = exc
        return out, failures


class BatchPolicy:
    """One call drives the whole batch: ``fn(images, plant) -> (N, 2)`` wheel PWM.

    ``images``: the plant's frames (an (N, H, W, 3) array from the simulator without an image filter), or
    None when ``camera`` is off. A batched policy is trusted code (a network, an expert): an exception is
    a bug and is raised, not recorded as an agent failure.
    """

    def __init__(self, fn: Callable[[Any, Plant], np.ndarray], n: int, name: str = "policy",
                 privileged: bool = False):
        self.fn = fn
        self.n = n
        self.names = [name] * n
        self.privileged = [privileged] * n

    def reset(self, seeds: Sequence[int]) -> dict[int, BaseException]:
        return {}

    def act(self, plant: Plant, images: Any, alive: np.ndarray) -> tuple[np.ndarray, dict[int, BaseException]]:
        return np.asarray(self.fn(images, plant), dtype=np.float64).reshape(self.n, 2).copy(), {}


class OpenLoopPolicy(BatchPolicy):
    """Every robot plays the same command sequence ``commands`` (T, 2), one row per frame (then zeros)."""

    def __init__(self, commands: np.ndarray, n: int, name: str = "open-loop"):
        self.commands = np.asarray(commands, dtype=np.float64).reshape(-1, 2)
        self._k = 0
        super().__init__(self._next, n, name)

    def reset(self, seeds: Sequence[int]) -> dict[int, BaseException]:
        self._k = 0
        return {}

    def _next(self, images: Any, plant: Plant) -> np.ndarray:
        row = self.commands[self._k] if self._k < len(self.commands) else np.zeros(2)
        self._k += 1
        return np.broadcast_to(row, (self.n, 2))


def rollout(
    plant: Plant,
    policy: Policy,
    seeds: Sequence[int],
    seconds: float,
    *,
    poses: Sequence[tuple[float, float, float] | None] | None = None,
    routes: Sequence[Sequence[str] | None] | None = None,
    camera: bool = True,
    allow_privileged: bool = True,
    on_frame: FrameHook | None = None,
    metas: Sequence[dict[str, Any] | None] | None = None,
) -> list[Trajectory]:
    """Play one episode per robot of ``plant`` for ``seconds`` (at most), driven by ``policy``.

    Robot i starts from ``seeds[i]`` (and ``poses[i]``, ``routes[i]``: turns at intersections, where
    given); ``camera`` renders frames for the policy; with ``allow_privileged=False`` a privileged
    driver is refused (:class:`PrivilegedAgentError`). ``on_frame(k, images, alive, plant)`` runs after each
    frame is observed. ``metas[i]`` is added to robot i's trajectory metadata.
    """
    n = plant.n
    if not (len(policy.names) == len(seeds) == n):
        raise ValueError(f"{len(policy.names)} drivers and {len(seeds)} seeds for a plant of {n} robots")
    poses = list(poses) if poses is not None else [None] * n
    routes = list(routes) if routes is not None else [None] * n
    metas = list(metas) if metas is not None else [None] * n
    if not allow_privileged:
        for name, privileged in zip(policy.names, policy.privileged, strict=True):
            if privileged:
                raise PrivilegedAgentError(f"agent {name!r} is privileged (reads the true lane pose); this run "
                                           f"allows camera-only agents")
    t0 = time.perf_counter()
    steps = plant.begin(seeds, poses, routes, seconds, camera, policy.privileged)
    t_plant, t_agent = time.perf_counter() - t0, 0.0
    events: list[list[Event]] = [[] for _ in range(n)]
    termination = [Termination.TIMEOUT] * n
    frames = [steps] * n
    alive = np.ones(n, dtype=bool)
    if isinstance(policy, AgentPolicy):
        policy.set_map(plant.map)
    at_start = policy.reset(seeds)
    for i, exc in at_start.items():
        events[i].append(failure_event(0.0, exc))
        termination[i], frames[i], alive[i] = Termination.AGENT_FAILURE, 0, False
    k = 0
    while k < steps and alive.any():
        failed, happened, dt_plant, dt_agent = _frame(plant, policy, k, alive, on_frame)
        for i, (t, exc) in failed.items():
            events[i].append(failure_event(t, exc))
            termination[i], frames[i] = Termination.AGENT_FAILURE, k
        for i, event, final in happened:
            events[i].append(event)
            if final:
                termination[i], frames[i], alive[i] = Termination(event.kind), k + 1, False
        t_plant += dt_plant
        t_agent += dt_agent
        k += 1
    plant.end()
    timing = {"sim_s": t_plant / n, "agent_s": t_agent / n}
    return [_trajectory(plant, policy, i, int(seeds[i]), seconds, frames[i], termination[i], events[i], metas[i],
                        routes[i], None if i in at_start else timing) for i in range(n)]


def _frame(plant: Plant, policy: Policy, k: int, alive: np.ndarray, on_frame: FrameHook | None, *,
           advance_all: bool = False,
           ) -> tuple[dict[int, tuple[float, BaseException]], list[tuple[int, Event, bool]], float, float]:
    """One frame of the engine: the plant's frames, the frame hook, the policy's commands, the plant advanced.

    A robot whose driver fails leaves ``alive`` (in place) before the plant advances, and keeps still. Returns the
    failures (robot → (time, exception)), the plant's events (robot, event, ends it), and the seconds spent in the
    plant and in the policy. The plant is not asked to advance once no robot is alive, unless ``advance_all`` (an
    auto-resetting plant restarts the robots whose drivers failed).
    """
    t0 = time.perf_counter()
    images = plant.frames(alive)
    if on_frame is not None:
        on_frame(k, images, alive, plant)
    t1 = time.perf_counter()
    commands, failed = policy.act(plant, images, alive)
    t2 = time.perf_counter()
    failures = {i: (plant.time(i), exc) for i, exc in failed.items()}
    for i in failures:
        alive[i] = False
    commands[~alive] = 0.0
    happened = plant.advance(commands, alive, k) if advance_all or alive.any() else []
    return failures, happened, (t1 - t0) + (time.perf_counter() - t2), t2 - t1


class ResettingPlant(Plant, Protocol):
    """A plant that never ends: a robot whose episode ends (its driver failed, the plant's own ending rule, its
    frames spent) starts its next episode at once (:class:`~proxybench.runner.autoreset.AutoResetPlant`)."""

    def open(self, camera: bool, privileged: Sequence[bool]) -> list[int]:
        """Start every robot's first episode; their seeds."""


def stream(plant: ResettingPlant, policy: Policy, until: Callable[[], bool], *, camera: bool = True,
           on_frame: FrameHook | None = None) -> int:
    """The engine's loop without an end, for a plant that resets each robot whose episode ended (the continuing
    stream of behaviour-cloning data collection: Gymnasium's and Brax's auto-reset): frames until ``until()``
    says enough (asked before each frame); how many frames that was.

    Per frame exactly what :func:`rollout` does (:func:`_frame`); a driver's failure ends its robot's episode
    (the plant restarts it; nothing is recorded, no trajectory is assembled: what the robots did is the
    policy's and the frame hook's to keep). A driver that fails to start is raised.
    """
    if len(policy.names) != plant.n:
        raise ValueError(f"{len(policy.names)} drivers for a plant of {plant.n} robots")
    seeds = plant.open(camera, policy.privileged)
    try:
        failed = policy.reset(seeds)
        if failed:
            raise next(iter(failed.values()))
        k = 0
        while not until():
            _frame(plant, policy, k, np.ones(plant.n, dtype=bool), on_frame, advance_all=True)
            k += 1
        return k
    finally:
        plant.end()


def lane_rows(plant: Plant) -> np.ndarray:
    """(N, LP.N) true lane-pose rows of a plant's robots, what a privileged batched policy reads (the expert): the
    simulator's array, or what a robot node serves (a row that is not valid where it serves none)."""
    sim = getattr(plant, "sim", None)
    if sim is not None:
        return sim.lane[: plant.n]
    rows = np.zeros((plant.n, LP.N))
    for i in range(plant.n):
        lp = plant.observation(i, None, True).lane_pose
        if lp is not None:
            rows[i] = lp.to_row()
    return rows


def _trajectory(plant: Plant, policy: Policy, i: int, seed: int, seconds: float, frames: int,
                termination: Termination, events: list[Event], meta: dict[str, Any] | None,
                route: Sequence[str] | None, timing: dict[str, float] | None) -> Trajectory:
    """The one trajectory assembly: the plant's samples and what it says, the driver, the caller's meta."""
    said = plant.meta(i)
    info = {"source": said.pop("source"), "agent": policy.names[i], "privileged": policy.privileged[i],
            "seed": seed, "episode_seconds": seconds if timing is not None else 0.0,
            "params": said.pop("params"), "proxybench_version": __version__, **said, **(meta or {})}
    rows = plant.samples(i, frames)
    pose = np.ascontiguousarray(rows[:, 1:4])
    if timing is None:  # the driver failed before the first frame: the start, and why
        return Trajectory.from_poses(plant.map, rows[:1, 0], pose[:1], meta=info, events=events,
                                     termination=termination)
    info["timing"] = timing
    if route is not None:
        info["route_plan"] = list(route)
    extra = {"v": rows[:, 4], "omega": rows[:, 5], "pwm_left": rows[:, 6], "pwm_right": rows[:, 7]}
    chosen = plant.route_lanes(i, frames) if policy.privileged[i] else None
    if chosen is not None:
        graph, pins, nexts, substeps, choices = chosen
        extra["route_segment"] = given_route_samples(graph, pose, pins, nexts, substeps)
        info["route_choices"] = choices
    return Trajectory.from_poses(plant.map, rows[:, 0], pose, extra=extra, meta=info, events=events,
                                 termination=termination, wheel_distance=plant.wheel_distance(i))


def failure_event(t: float, exc: BaseException) -> Event:
    """The ``agent_failure`` event of an exception: its words, reason and, for a node, exit status and last
    stderr lines (e.g. its traceback)."""
    detail = getattr(exc, "detail", None) or "".join(traceback.format_exception_only(exc)).strip()
    return Event(t, Termination.AGENT_FAILURE, f"{type(exc).__name__}: {detail}",
                 reason=getattr(exc, "reason", type(exc).__name__), exit_code=getattr(exc, "exit_code", None),
                 stderr_tail=tuple(getattr(exc, "stderr_tail", None) or ())[-20:])
