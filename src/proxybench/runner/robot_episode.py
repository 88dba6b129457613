"""One episode of an agent driving a robot reached through the robot protocol (simulator node or real robot).

The control loop is the in-process runner's (:func:`~proxybench.runner.episode.run_episode`): one camera
frame, one decision, one frame of physics with that command held; the same checks end the episode. Here
each frame is one pipelined exchange with the robot node (commands, step, sim state, robot state, next
observations), and the trajectory is built from what the robot reports: its physics-rate trace when it
sends the proxybench extension (the simulator node does, so a run through the protocol equals the
in-process run sample for sample), else one sample per frame from ``robot_state``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from proxybench import __version__
from proxybench.agents.base import Agent, Observation
from proxybench.domain.lanes import LaneNetwork
from proxybench.domain.maps import Map, load_map
from proxybench.domain.routes import given_route_samples
from proxybench.protocol import jpeg
from proxybench.protocol import robot_wire as rw
from proxybench.protocol.robot_process import RemoteRobot
from proxybench.runner.episode import PrivilegedAgentError, _failure_event
from proxybench.tasks.trajectory import Trajectory

__all__ = ["RobotLacksGroundTruth", "run_episode_on_robot"]


class RobotLacksGroundTruth(PrivilegedAgentError):
    """A privileged agent was given a robot that does not report the true lane pose."""


def _observation(obs: rw.RobotObservationsData, privileged: bool) -> Observation:
    o = obs.observations
    image = jpeg.decode_received(o.jpg) if o.jpg else None
    if not privileged:
        return Observation(image, o.timestamp, o.odometry, o.resolution)
    return Observation(image, o.timestamp, o.odometry, o.resolution, obs.lane_pose, obs.route)


def _samples(state: rw.RobotStateData) -> np.ndarray:
    """(n, 8) rows t, x, y, θ, v, ω, pwm_left, pwm_right: the tick trace, else the one reported state."""
    if state.trace is not None:
        return np.column_stack([state.trace[k] for k in rw.TRACE_COLUMNS])
    return np.array([[state.t_effective, *state.pose, state.v, state.omega, *state.pwm]])


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
    if agent.privileged and not allow_privileged:
        raise PrivilegedAgentError(
            f"agent {agent.name!r} is privileged (reads the true lane pose); this run allows camera-only agents")
    m = load_map(map_) if isinstance(map_, str) else map_
    t_robot = t_agent = 0.0
    t0 = time.perf_counter()
    info = robot.start_episode(m, seed, pose=pose, seconds=seconds, camera=camera, route=route)
    frame_dt = 1.0 / info.frame_rate
    steps = max(1, round(seconds / frame_dt))
    states = [robot.state(0.0)]
    obs = robot.observations(0.0)
    if agent.privileged and obs.lane_pose is None:
        raise RobotLacksGroundTruth(f"robot {robot.command!r} ({info.kind}) reports no true lane pose, which the "
                                    f"privileged agent {agent.name!r} needs")
    t_robot += time.perf_counter() - t0
    events: list[dict[str, Any]] = []
    termination = "timeout"
    try:
        agent.reset(int(seed))
        started = True
    except Exception as exc:  # a failing agent ends its episode, never the run
        events.append(_failure_event(0.0, exc))
        termination, started = "agent_failure", False
    for k in range(steps if started else 0):
        observation = _observation(obs, agent.privileged)
        if on_frame is not None:
            on_frame(k, observation.camera)
        t1 = time.perf_counter()
        try:
            command = np.asarray(agent.act(observation), dtype=np.float64)
            if command.shape != (2,) or not np.all(np.isfinite(command)):
                raise ValueError(f"agent returned {command!r}, expected 2 finite wheel PWM values")
        except Exception as exc:  # likewise: recorded as the reason the episode ended
            events.append(_failure_event(observation.time, exc))
            termination = "agent_failure"
            break
        t2 = time.perf_counter()
        sim_state, state, obs = robot.frame(observation.time, np.clip(command, -1.0, 1.0), (k + 1) * frame_dt,
                                            observe=k + 1 < steps)
        t_robot += time.perf_counter() - t2
        t_agent += t2 - t1
        states.append(state)
        end = sim_state.terminations.get(robot.robot_name)
        if end is not None and end.termination != "timeout":
            event = {"t": end.when, "kind": end.termination, "message": end.desc}
            events.append(event if end.hit is None else event | {"with": end.hit})
            termination = end.termination
            break
    rows = np.vstack([_samples(s) for s in states])
    extra = {"v": rows[:, 4], "omega": rows[:, 5], "pwm_left": rows[:, 6], "pwm_right": rows[:, 7]}
    info_meta = {
        "source": info.kind, "agent": agent.name, "privileged": agent.privileged, "seed": int(seed),
        "episode_seconds": seconds, "params": info.params, "proxybench_version": __version__,
        "robot": {"command": robot.command, "kind": info.kind, "name": robot.robot_name},
        **(meta or {}), "timing": {"sim_s": t_robot, "agent_s": t_agent},
    }
    if route is not None:
        info_meta["route_plan"] = list(route)
    routes = [s.route for s in states if s.route is not None]
    if agent.privileged and routes and routes[-1].active and info.physics_rate is not None:
        pins = [p for r in routes for p in r.pins]
        nexts = [n for r in routes for n in r.nexts]
        substeps = round(info.physics_rate / info.frame_rate)
        extra["route_segment"] = given_route_samples(LaneNetwork(m), rows[:, 1:4], np.array(pins, dtype=np.int64),
                                                     np.array(nexts, dtype=np.int64), substeps)
        info_meta["route_choices"] = list(routes[-1].choices)
    return Trajectory.from_poses(m, rows[:, 0], rows[:, 1:4], extra=extra, meta=info_meta, events=events,
                                 termination=termination, wheel_distance=info.wheel_distance)
