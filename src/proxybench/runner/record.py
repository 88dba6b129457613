"""One episode recorded for people: the trajectory, a video (camera beside top-down) and a PNG strip of frames.

``proxybench run`` and ``evaluate --video`` record through :func:`record_run`, whatever the domain: a
simulated one (the batched simulator, its NPCs) or a robot node (``DomainSpec.robot``). The episode is the
engine's (:func:`~proxybench.runner.rollout.rollout`); this module only watches its frames.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.agents.base import Agent
from proxybench.domain.kinds import DomainKind
from proxybench.domain.maps import Map, load_map
from proxybench.domain.simulator import Simulator
from proxybench.domain.topdown import top_down
from proxybench.media import VideoWriter, side_by_side, write_strip
from proxybench.runner.episode import SimPlant
from proxybench.runner.jobs import DomainSpec
from proxybench.runner.outcomes import camera_filter
from proxybench.runner.robot_episode import RobotLacksGroundTruth
from proxybench.runner.robots import open_robot
from proxybench.runner.rollout import AgentPolicy, rollout
from proxybench.runner.streams import StreamRecorder, StreamSpec, with_fixtures
from proxybench.tasks.trajectory import Trajectory

__all__ = ["Recording", "record_run"]


@dataclass
class Recording:
    """A recorded episode: its trajectory, the files written for people, and the wall time it took."""

    trajectory: Trajectory
    files: list[Path] = field(default_factory=list)
    wall_s: float = 0.0


def record_run(
    domain: DomainSpec, agent: Agent, map_: Map | str, seed: int, seconds: float, out: str | Path, *,
    frame_rate: float | None = None, stem: str = "drive", video: bool = True,
    pose: tuple[float, float, float] | None = None, route: Sequence[str] | None = None, npcs: Any = None,
    strip_frames: int = 12, on_frame: Callable[[int], None] | None = None, meta: dict[str, Any] | None = None,
    streams: StreamSpec | None = None,
) -> Recording:
    """Drive ``agent`` in ``domain`` for ``seconds`` and write ``<stem>.mp4`` (if ``video``) and
    ``<stem>_strip.png`` into ``out``.

    In a simulated domain the camera is always rendered (also for privileged agents, which do not see it)
    so that people can; a robot node sends frames only to camera agents. ``frame_rate`` [Hz]: what a robot
    node is asked to step at (a simulated domain's comes from its θ). A robot node that fails raises
    :class:`~proxybench.protocol.RobotFailure`; a privileged agent on a robot without the true lane pose,
    :class:`~proxybench.runner.robot_episode.RobotLacksGroundTruth`. ``streams``: also record these fixed cameras
    (a lab's watchtowers, simulated domains only; their fixtures join the map) into ``out/watchtowers/<camera>/``
    (``runner.streams``).
    """
    import time

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    m = load_map(map_) if isinstance(map_, str) else map_
    t0 = time.perf_counter()
    if domain.kind is DomainKind.ROBOT and streams is not None:
        raise ValueError("watchtower streams are simulated: they need a simulated domain, not a robot node")
    if domain.kind is DomainKind.ROBOT:
        robot = open_robot(domain, frame_rate)
        try:
            rec = _record(robot.plant(m), agent, seed, seconds, out, stem, video, pose, route, strip_frames,
                          on_frame, meta)
        finally:
            robot.close()
    else:
        world = with_fixtures(m, streams.fixtures) if streams is not None else m  # the lab's calibration tags
        sim = Simulator(world, domain.params, npcs=npcs)
        recorder = StreamRecorder(sim, streams, out / "watchtowers") if streams is not None else None
        try:
            rec = _record(SimPlant(sim, camera_filter()), agent, seed, seconds, out, stem, video, pose, route,
                          strip_frames, on_frame, meta, recorder)
        finally:
            if recorder is not None:
                recorder.close()
        if recorder is not None:
            rec.files.insert(0, recorder.out)
    rec.wall_s = time.perf_counter() - t0
    return rec


def _view(plant) -> np.ndarray:
    """Top-down view of the plant's map with its robot (and, in simulation, the episode's NPCs and extras)."""
    m = plant.map
    px = max(64, min(240, 720 // max(m.width, m.height)))
    if isinstance(plant, SimPlant):
        s = plant.sim
        objects, npcs = s.world_view(0)
        return top_down(m, s.state[:1, :3], px_per_tile=px, params=s.params[0], objects=objects, npc_poses=npcs)
    return top_down(m, np.asarray([plant.samples(0, 10**9)[-1, 1:4]]), px_per_tile=px)


def _record(plant, agent: Agent, seed: int, seconds: float, out: Path, stem: str, video: bool, pose, route,
            strip_frames: int, on_frame, meta, recorder: StreamRecorder | None = None) -> Recording:
    every = 1
    strip: list[np.ndarray] = []
    labels: list[str] = []
    files: list[Path] = []
    writer: VideoWriter | None = None

    def frame(k: int, images, alive: np.ndarray, p) -> None:
        nonlocal writer, every
        if k == 0:  # the plant knows its frame rate once the episode began
            every = max(1, round(seconds * p.frame_rate) // max(1, strip_frames - 1))
        img = images[0] if images is not None else None
        if img is None and isinstance(p, SimPlant):
            img = p.sim.render()[0]  # for people: a privileged agent does not see it
        if img is not None:
            if video and writer is None:
                writer = VideoWriter(out / f"{stem}.mp4", p.frame_rate)
            if writer is not None:
                writer.append(side_by_side(img, _view(p)))
            if k % every == 0 and len(strip) < strip_frames:
                strip.append(img)
                labels.append(f"t={k / p.frame_rate:.1f}s")
        if recorder is not None and alive[0]:
            recorder.frame(p.time(0))
        if on_frame is not None:
            on_frame(k)

    try:
        camera = not agent.privileged or getattr(agent, "wants_camera", False)
        traj = rollout(plant, AgentPolicy([agent]), [seed], seconds, poses=[pose], camera=camera, routes=[route],
                       on_frame=frame, metas=[meta])[0]
    except RobotLacksGroundTruth as exc:
        raise RobotLacksGroundTruth(f"{exc}, which the privileged agent {agent.name!r} needs") from None
    finally:
        if writer is not None:
            writer.close()
            files.append(writer.path)
    if strip:
        files.append(write_strip(strip, out / f"{stem}_strip.png", labels))
    return Recording(traj, files)
