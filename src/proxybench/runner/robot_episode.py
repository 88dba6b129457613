"""Episodes on a robot reached through the robot protocol (simulator node or real robot's bridge).

:class:`RobotPlant` makes a :class:`~proxybench.protocol.RemoteRobot` a plant of the episode engine
(:func:`~proxybench.runner.rollout.rollout`), so the control loop, the ending rule and the trajectory
assembly are the in-process runner's: one camera frame, one decision, one frame of physics with that
command held. Here each frame is one pipelined exchange with the robot node (commands, step, sim state,
robot state, next observations), the robot says when its episode ended (collision, off the road), and
the trajectory is built from what it reports: its physics-rate trace when it sends the proxybench
extension (the simulator node does, so a run through the protocol equals the in-process run sample for
sample), else one sample per frame from ``robot_state``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.domain.lanes import LaneNetwork
from proxybench.domain.maps import Map, load_map
from proxybench.domain.routes import RouteGraph
from proxybench.protocol import jpeg
from proxybench.protocol import robot_wire as rw
from proxybench.protocol.robot_process import RemoteRobot
from proxybench.runner.rollout import AgentPolicy, PrivilegedAgentError, rollout
from proxybench.tasks.trajectory import Event, Termination, Trajectory

__all__ = ["RobotLacksGroundTruth", "RobotPlant", "run_episode_on_plant", "run_episode_on_robot"]


class RobotLacksGroundTruth(PrivilegedAgentError):
    """A privileged agent was given a robot that does not report the true lane pose."""


def _samples(state: rw.RobotStateData) -> np.ndarray:
    """(n, 8) rows t, x, y, θ, v, ω, pwm_left, pwm_right: the tick trace, else the one reported state."""
    if state.trace is not None:
        return np.column_stack([state.trace[k] for k in rw.TRACE_COLUMNS])
    return np.array([[state.t_effective, *state.pose, state.v, state.omega, *state.pwm]])


class RobotPlant:
    """One robot node as a plant of one robot, on ``map_`` (sent to the robot with ``set_map``).

    A failing robot raises :class:`~proxybench.protocol.RobotFailure` from :meth:`begin` or
    :meth:`advance`: an episode whose robot failed has no valid trajectory.
    """

    n = 1

    def __init__(self, robot: RemoteRobot, map_: Map | str):
        self.robot = robot
        self.map = load_map(map_) if isinstance(map_, str) else map_
        self._graph: RouteGraph | None = None

    def begin(self, seeds: Sequence[int], poses: Sequence[Any], routes: Sequence[Any], seconds: float,
              camera: bool, privileged: Sequence[bool]) -> int:
        robot = self.robot
        route = None if routes[0] is None else list(routes[0])
        self.info = robot.start_episode(self.map, int(seeds[0]), pose=poses[0], seconds=seconds, camera=camera,
                                        route=route)
        self.frame_dt = 1.0 / self.info.frame_rate
        self.steps = max(1, round(seconds / self.frame_dt))
        self.states = [robot.state(0.0)]
        self.obs: rw.RobotObservationsData | None = robot.observations(0.0)
        if privileged[0] and self.obs.lane_pose is None:
            raise RobotLacksGroundTruth(f"robot {robot.command!r} ({self.info.kind}) reports no true lane pose")
        return self.steps

    @property
    def frame_rate(self) -> float:
        """[Hz] camera frames per second, as the robot said when the episode began."""
        return self.info.frame_rate

    def encoded_frame(self, i: int) -> bytes | None:
        """The current camera frame as the robot sent it (JPEG bytes), before decoding."""
        return self.obs.observations.jpg or None

    def frames(self, alive: np.ndarray) -> list[np.ndarray | None]:
        o = self.obs.observations
        return [jpeg.decode_received(o.jpg) if o.jpg else None]

    def observation(self, i: int, image: np.ndarray | None, privileged: bool) -> Observation:
        o = self.obs.observations
        if not privileged:
            return Observation(image, o.timestamp, o.odometry, o.resolution)
        return Observation(image, o.timestamp, o.odometry, o.resolution, self.obs.lane_pose, self.obs.route,
                           tuple(self.states[-1].pose))

    def time(self, i: int) -> float:
        return self.obs.observations.timestamp

    def advance(self, commands: np.ndarray, alive: np.ndarray, k: int) -> list[tuple[int, Event, bool]]:
        robot = self.robot
        sim_state, state, self.obs = robot.frame(self.time(0), np.clip(commands[0], -1.0, 1.0),
                                                 (k + 1) * self.frame_dt, observe=k + 1 < self.steps)
        self.states.append(state)
        end = sim_state.terminations.get(robot.robot_name)
        if end is None or end.termination is Termination.TIMEOUT:  # the episode's length is the engine's to count
            return []
        return [(0, Event(end.when, end.termination, end.desc, with_=end.hit), True)]

    def samples(self, i: int, frames: int) -> np.ndarray:
        return np.vstack([_samples(s) for s in self.states])

    def route_lanes(self, i: int, frames: int) -> tuple[Any, np.ndarray, np.ndarray, int, list] | None:
        routes = [s.route for s in self.states if s.route is not None]
        if not (routes and routes[-1].active and self.info.physics_rate is not None):
            return None
        if self._graph is None:
            self._graph = RouteGraph(LaneNetwork(self.map))
        pins = np.array([p for r in routes for p in r.pins], dtype=np.int64)
        nexts = np.array([n for r in routes for n in r.nexts], dtype=np.int64)
        return self._graph, pins, nexts, round(self.info.physics_rate / self.info.frame_rate), list(routes[-1].choices)

    def meta(self, i: int) -> dict[str, Any]:
        robot, info = self.robot, self.info
        said = {"command": robot.command, "kind": info.kind, "name": robot.robot_name}
        if isinstance(info.raw.get("simulator"), dict):  # which simulator a simulated node is (gym-duckietown, ...)
            said["simulator"] = info.raw["simulator"]
        return {"source": info.kind, "params": info.params, "robot": said}

    def wheel_distance(self, i: int) -> float:
        return self.info.wheel_distance

    def end(self) -> None:
        pass


def run_episode_on_robot(
    robot: RemoteRobot,
    agent: Agent,
    seed: int,
    seconds: float,
    *,
    map_: Map | str,
    pose: tuple[float, float, float] | None = None,
    route: list[str] | None = None,
    camera: bool = True,
    allow_privileged: bool = True,
    on_frame: Callable[[int, np.ndarray | None], None] | None = None,
    meta: dict[str, Any] | None = None,
) -> Trajectory:
    """Drive ``robot`` with ``agent`` for ``seconds`` on ``map_`` (or until the robot reports the end).

    Arguments as :func:`~proxybench.runner.episode.run_episode` (``route``: turns at intersections, for a
    robot that simulates route choices); ``map_`` is sent to the robot
    (``set_map``) and scores the trajectory. Camera frames reach the agent as decoded JPEG, exactly the
    pixels an in-process camera agent sees. An exception from the agent ends the episode with
    termination ``agent_failure``; a failing robot raises :class:`~proxybench.protocol.RobotFailure`
    (there is no valid trajectory then). A privileged agent needs a robot that reports the true lane pose.
    """
    return run_episode_on_plant(RobotPlant(robot, map_), agent, seed, seconds, pose=pose, route=route, camera=camera,
                                allow_privileged=allow_privileged, on_frame=on_frame, meta=meta)


def run_episode_on_plant(
    plant: Any, agent: Agent, seed: int, seconds: float, *, pose: tuple[float, float, float] | None = None,
    route: list[str] | None = None, camera: bool = True, allow_privileged: bool = True,
    on_frame: Callable[[int, np.ndarray | None], None] | None = None, meta: dict[str, Any] | None = None,
) -> Trajectory:
    """:func:`run_episode_on_robot` on a plant of one robot already made (a robot node's or a DTPS robot's)."""
    hook = None if on_frame is None else (lambda k, images, alive, plant: on_frame(k, images[0]))
    try:
        return rollout(plant, AgentPolicy([agent]), [seed], seconds, poses=[pose], routes=[route], camera=camera,
                       allow_privileged=allow_privileged, on_frame=hook, metas=[meta])[0]
    except RobotLacksGroundTruth as exc:
        raise RobotLacksGroundTruth(f"{exc}, which the privileged agent {agent.name!r} needs") from None
