"""One episode of one in-process agent in one simulated domain, recorded at the physics rate."""

from __future__ import annotations

import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from proxybench import __version__
from proxybench.agents.base import Agent, Observation
from proxybench.domain.dynamics import ST, TRACE_FIELDS, wheel_ticks
from proxybench.domain.lane_pose import LanePose
from proxybench.domain.routes import given_route_samples
from proxybench.domain.simulator import Simulator
from proxybench.domain.worlds import HIT_KINDS
from proxybench.runner.npcs import NpcDrivers
from proxybench.tasks.trajectory import Trajectory

__all__ = ["PrivilegedAgentError", "run_episode", "run_episodes"]


class PrivilegedAgentError(ValueError):
    """A privileged agent (one that reads the true lane pose) was given to a camera-only run."""


def _observation(sim: Simulator, i: int, image: np.ndarray | None, privileged: bool) -> Observation:
    s = sim.state[i]
    res = sim.params[i].encoder_resolution
    ticks = wheel_ticks(s[[ST.WHEEL_L, ST.WHEEL_R]], res)
    lp = LanePose.from_row(sim.lane[i]) if privileged else None
    route = sim.routes.info(i, sim.lane[i]) if privileged else None
    return Observation(image, float(sim.time[i]), (float(ticks[0] * res), float(ticks[1] * res)), res, lp, route)


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
) -> list[Trajectory]:
    """Episodes of N agents at once, robot i of ``sim`` driven by ``agents[i]`` from ``seeds[i]``.

    Physics and rendering advance all robots in one compiled call per frame; each robot's episode is
    exactly what it would be alone (robot i meets only the NPCs of its own world), so a batch gives the same
    trajectories as N single runs. A robot whose episode has ended keeps still until the others are done.
    The simulator's NPC robots are driven by the zoo agents their specs name (``runner.npcs``).

    ``routes[i]``: robot i's turns at intersections. Privileged agents are measured against the exits
    the simulator chose for them (recorded as ``route_segment``); camera agents are free, and their
    route is the exits they took (``proxybench.domain.routes``).
    """
    n = sim.n
    if not (len(agents) == len(seeds) == n):
        raise ValueError(f"{len(agents)} agents and {len(seeds)} seeds for a simulator of {n} robots")
    poses = list(poses) if poses is not None else [None] * n
    metas = list(metas) if metas is not None else [None] * n
    routes = list(routes) if routes is not None else [None] * n
    for a in agents:
        if a.privileged and not allow_privileged:
            raise PrivilegedAgentError(
                f"agent {a.name!r} is privileged (reads the true lane pose); this run allows camera-only agents"
            )
    steps = max(1, round(seconds / sim.frame_dt))
    trace = np.zeros((n, steps, sim.substeps, len(TRACE_FIELDS)))
    lanes_chosen = np.full((2, n, steps), -1, dtype=np.int64)  # per frame: pinned lane, lane chosen ahead
    for i in range(n):
        sim.reset(i, int(seeds[i]), poses[i], routes[i])
    start = sim.state.copy()
    drivers = NpcDrivers(sim, image_filter) if sim.worlds.k else None
    if drivers is not None:
        drivers.reset(seeds)
    events: list[list[dict[str, Any]]] = [[] for _ in range(n)]
    termination = ["timeout"] * n
    done_frames = [steps] * n
    alive = np.ones(n, dtype=bool)
    failed_at_start: dict[int, Trajectory] = {}
    for i, a in enumerate(agents):
        try:
            a.reset(int(seeds[i]))
        except Exception as exc:  # a failing agent ends its episode, never the run
            failed_at_start[i] = _failed_at_start(sim, i, a, int(seeds[i]), start[i], exc, metas[i])
            alive[i] = False
    commands = np.zeros((n, 2))
    t_sim = t_agent = 0.0
    k = 0
    while k < steps and alive.any():
        t0 = time.perf_counter()
        images: list[np.ndarray | None] = [None] * n
        npc_cams = drivers.wants_camera(alive) if drivers is not None else None
        if camera or npc_cams is not None:
            frames = sim.render(active=alive if camera else np.zeros(n, dtype=bool), npc_active=npc_cams)
            if camera:
                images = [None if not alive[i] else image_filter(f) if image_filter is not None else f
                          for i, f in enumerate(frames)]
        if on_frame is not None:
            on_frame(k, images, sim)
        t1 = time.perf_counter()
        for i in np.flatnonzero(alive):
            try:
                command = np.asarray(agents[i].act(_observation(sim, i, images[i], agents[i].privileged)),
                                     dtype=np.float64)
                if command.shape != (2,) or not np.all(np.isfinite(command)):
                    raise ValueError(f"agent returned {command!r}, expected 2 finite wheel PWM values")
                commands[i] = command
            except Exception as exc:  # likewise: recorded as the reason the episode ended
                events[i].append(_failure_event(float(sim.time[i]), exc))
                termination[i], done_frames[i], alive[i] = "agent_failure", k, False
                commands[i] = 0.0
        t2 = time.perf_counter()
        commands[~alive] = 0.0
        lanes_chosen[:, :, k] = sim.routes.pin[:n], sim.routes.next[:n]  # the egos' rows (NPCs follow)
        sim.step(commands, trace[:, k], None if drivers is None else drivers.act(alive))
        t3 = time.perf_counter()
        t_sim += (t1 - t0) + (t3 - t2)
        t_agent += t2 - t1
        for w, event in drivers.events() if drivers is not None else ():
            if alive[w]:
                events[w].append(event)
        for i in np.flatnonzero(alive & sim.collided):
            what = HIT_KINDS[int(sim.hit_kind[i])] or "map object"
            events[i].append({"t": float(sim.time[i]), "kind": "collision", "with": what,
                              "message": f"the robot came too close to a {what}"})
            termination[i], done_frames[i], alive[i] = "collision", k + 1, False
        for i in np.flatnonzero(alive & sim.off_road):
            events[i].append({"t": float(sim.time[i]), "kind": "off_road",
                              "message": "the robot centre left the drivable area"})
            termination[i], done_frames[i], alive[i] = "off_road", k + 1, False
        k += 1
    if drivers is not None:
        drivers.close()
    timing = {"sim_s": t_sim / n, "agent_s": t_agent / n}
    out = []
    for i in range(n):
        if i in failed_at_start:
            out.append(failed_at_start[i])
            continue
        rows = trace[i, : done_frames[i]].reshape(-1, len(TRACE_FIELDS))
        t = np.arange(rows.shape[0] + 1) * sim.params[i].physics_dt
        pose = np.vstack([start[i, :3][None], rows[:, :3]])
        extra = {"v": np.r_[start[i, ST.V], rows[:, 3]], "omega": np.r_[start[i, ST.OMEGA], rows[:, 4]],
                 "pwm_left": np.r_[0.0, rows[:, 5]], "pwm_right": np.r_[0.0, rows[:, 6]]}
        info = _meta(sim, i, agents[i], int(seeds[i]), seconds, metas[i]) | {"timing": timing}
        if routes[i] is not None:
            info["route_plan"] = list(routes[i])
        if not sim.worlds.traffic[i].empty:
            info["npcs"] = sim.worlds.traffic[i].to_dict()
        if agents[i].privileged and sim.routes.active:
            extra["route_segment"] = given_route_samples(sim.routes.graph, pose, *lanes_chosen[:, i, : done_frames[i]],
                                                         sim.substeps)
            info["route_choices"] = list(sim.routes.choices[i])
        out.append(Trajectory.from_poses(sim.map, t, pose, extra=extra, meta=info, events=events[i],
                                         termination=termination[i], wheel_distance=sim.params[i].wheel_distance))
    return out


def _failure_event(t: float, exc: BaseException) -> dict[str, Any]:
    detail = getattr(exc, "detail", None) or "".join(traceback.format_exception_only(exc)).strip()
    event = {"t": t, "kind": "agent_failure", "message": f"{type(exc).__name__}: {detail}",
             "reason": getattr(exc, "reason", type(exc).__name__)}
    if getattr(exc, "exit_code", None) is not None:  # a node's exit status and last words (e.g. its traceback)
        event["exit_code"] = exc.exit_code
    if getattr(exc, "stderr_tail", None):
        event["stderr_tail"] = list(exc.stderr_tail)[-20:]
    return event


def _failed_at_start(sim, i, agent, seed, start, exc, meta) -> Trajectory:
    return Trajectory.from_poses(sim.map, np.zeros(1), start[None, :3], meta=_meta(sim, i, agent, seed, 0.0, meta),
                                 events=[_failure_event(0.0, exc)], termination="agent_failure")


def _meta(sim: Simulator, i: int, agent: Agent, seed: int, seconds: float,
          extra: dict[str, Any] | None) -> dict[str, Any]:
    return {
        "source": "simulation",
        "agent": agent.name,
        "privileged": agent.privileged,
        "seed": seed,
        "episode_seconds": seconds,
        "params": sim.params[i].model_dump(mode="json"),
        "proxybench_version": __version__,
        **(extra or {}),
    }
