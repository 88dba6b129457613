"""One episode recorded for people: a video (camera beside top-down) and a PNG strip of frames."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from proxybench.agents.base import Agent
from proxybench.domain.simulator import Simulator
from proxybench.domain.topdown import top_down
from proxybench.media import VideoWriter, side_by_side, write_strip
from proxybench.runner.episode import run_episode
from proxybench.runner.outcomes import camera_filter
from proxybench.tasks.trajectory import Trajectory

__all__ = ["record_episode"]


def record_episode(
    sim: Simulator, agent: Agent, seed: int, seconds: float, out: str | Path, *, stem: str = "drive",
    video: bool = True, pose: tuple[float, float, float] | None = None, strip_frames: int = 12,
    on_frame: Callable[[int], None] | None = None, meta: dict[str, Any] | None = None,
    route: Sequence[str] | None = None,
) -> tuple[Trajectory, list[Path]]:
    """Run one episode and write ``<stem>.mp4`` (if ``video``) and ``<stem>_strip.png`` into ``out``.

    The camera is always rendered (even for privileged agents, which do not see it) so that people can.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    fps = 1.0 / sim.frame_dt
    steps = max(1, round(seconds * fps))
    every = max(1, steps // max(1, strip_frames - 1))
    strip: list[np.ndarray] = []
    labels: list[str] = []
    files: list[Path] = []
    writer = VideoWriter(out / f"{stem}.mp4", fps) if video else None
    px = max(64, min(240, 720 // max(sim.map.width, sim.map.height)))

    def frame(k: int, image: np.ndarray | None, s: Simulator) -> None:
        img = image if image is not None else s.render()[0]
        if writer is not None:
            objects, npcs = s.world_view(0)  # the episode's own extras, pedestrians and NPC robots
            writer.append(side_by_side(img, top_down(s.map, s.state[:1, :3], px_per_tile=px, params=s.params[0],
                                                     objects=objects, npc_poses=npcs)))
        if k % every == 0:
            strip.append(img)
            labels.append(f"t={k / fps:.1f}s")
        if on_frame is not None:
            on_frame(k)

    try:
        traj = run_episode(sim, agent, seed, seconds, pose=pose, camera=not agent.privileged, on_frame=frame,
                           image_filter=camera_filter(), meta=meta, route=route)
    finally:
        if writer is not None:
            writer.close()
            files.append(writer.path)
    if strip:
        files.append(write_strip(strip, out / f"{stem}_strip.png", labels))
    return traj, files
