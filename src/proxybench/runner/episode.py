"""One episode of one in-process agent in one simulated domain, recorded at the physics rate."""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable
from typing import Any

import numpy as np

from proxybench import __version__
from proxybench.agents.base import Agent, Observation
from proxybench.domain.dynamics import ST, TRACE_FIELDS, wheel_ticks
from proxybench.domain.lane_pose import LanePose
from proxybench.domain.simulator import Simulator
from proxybench.tasks.trajectory import Trajectory

__all__ = ["PrivilegedAgentError", "run_episode"]


class PrivilegedAgentError(ValueError):
    """A privileged agent (one that reads the true lane pose) was given to a camera-only run."""


def _observation(sim: Simulator, image: np.ndarray | None, privileged: bool) -> Observation:
    s = sim.state[0]
    res = sim.params[0].encoder_resolution
    ticks = wheel_ticks(s[[ST.WHEEL_L, ST.WHEEL_R]], res)
    lp = LanePose.from_row(sim.lane[0]) if privileged else None
    return Observation(image, float(sim.time[0]), (float(ticks[0] * res), float(ticks[1] * res)), res, lp)


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
) -> Trajectory:
    """Drive robot 0 of ``sim`` with ``agent`` for ``seconds`` (or until it leaves the road or fails).

    The agent sees a frame every 1/frame_rate s and its command is held until the next frame. The
    trajectory has one sample per physics tick. ``image_filter`` transforms frames before the agent sees
    them (e.g. a JPEG round trip, so that in-process and remote agents see the same pixels);
    ``on_frame(k, image, sim)`` is called after each frame (e.g. to write a video). With
    ``allow_privileged=False`` (camera-only evaluation) a privileged agent is refused.
    An exception from the agent ends the episode with termination ``agent_failure``; it is not raised.
    """
    if agent.privileged and not allow_privileged:
        raise PrivilegedAgentError(
            f"agent {agent.name!r} is privileged (reads the true lane pose); this run allows camera-only agents"
        )
    sim.reset(0, seed, pose)
    steps = max(1, round(seconds / sim.frame_dt))
    sub = sim.substeps
    trace = np.zeros((steps, sub, len(TRACE_FIELDS)))
    start = sim.state[0].copy()
    events: list[dict[str, Any]] = []
    termination, done_frames = "timeout", steps
    try:
        agent.reset(seed)
    except Exception as exc:  # a failing agent ends its episode, never the run
        return _failed_at_start(sim, agent, seed, start, exc, meta)
    t_sim = t_agent = 0.0
    for k in range(steps):
        t0 = time.perf_counter()
        image = sim.render()[0] if camera else None
        if image is not None and image_filter is not None:
            image = image_filter(image)
        if on_frame is not None:
            on_frame(k, image, sim)
        t1 = time.perf_counter()
        t_sim += t1 - t0
        try:
            command = np.asarray(agent.act(_observation(sim, image, agent.privileged)), dtype=np.float64)
            if command.shape != (2,) or not np.all(np.isfinite(command)):
                raise ValueError(f"agent returned {command!r}, expected 2 finite wheel PWM values")
        except Exception as exc:  # likewise: recorded as the reason the episode ended
            events.append(_failure_event(float(sim.time[0]), exc))
            termination, done_frames = "agent_failure", k
            break
        t2 = time.perf_counter()
        t_agent += t2 - t1
        sim.step(command[None], trace[k][None])
        t_sim += time.perf_counter() - t2
        if sim.off_road[0]:
            t_off = float(sim.time[0])
            events.append({"t": t_off, "kind": "off_road", "message": "the robot centre left the drivable area"})
            termination, done_frames = "off_road", k + 1
            break
    rows = trace[:done_frames].reshape(-1, len(TRACE_FIELDS))
    t = np.arange(rows.shape[0] + 1) * sim.params[0].physics_dt
    poses = np.vstack([start[None, :3], rows[:, :3]])
    extra = {"v": np.r_[start[ST.V], rows[:, 3]], "omega": np.r_[start[ST.OMEGA], rows[:, 4]],
             "pwm_left": np.r_[0.0, rows[:, 5]], "pwm_right": np.r_[0.0, rows[:, 6]]}
    info = _meta(sim, agent, seed, seconds, meta) | {"timing": {"sim_s": t_sim, "agent_s": t_agent}}
    return Trajectory.from_poses(sim.map, t, poses, extra=extra, meta=info, events=events, termination=termination,
                                 wheel_distance=sim.params[0].wheel_distance)


def _failure_event(t: float, exc: BaseException) -> dict[str, Any]:
    detail = getattr(exc, "detail", None) or "".join(traceback.format_exception_only(exc)).strip()
    return {"t": t, "kind": "agent_failure", "message": f"{type(exc).__name__}: {detail}",
            "reason": getattr(exc, "reason", type(exc).__name__)}


def _failed_at_start(sim, agent, seed, start, exc, meta) -> Trajectory:
    return Trajectory.from_poses(sim.map, np.zeros(1), start[None, :3], meta=_meta(sim, agent, seed, 0.0, meta),
                                 events=[_failure_event(0.0, exc)], termination="agent_failure")


def _meta(sim: Simulator, agent: Agent, seed: int, seconds: float, extra: dict[str, Any] | None) -> dict[str, Any]:
    return {
        "source": "simulation",
        "agent": agent.name,
        "privileged": agent.privileged,
        "seed": seed,
        "episode_seconds": seconds,
        "params": sim.params[0].model_dump(mode="json"),
        "proxybench_version": __version__,
        **(extra or {}),
    }
