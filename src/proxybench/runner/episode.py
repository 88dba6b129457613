"""One episode of one in-process agent in one simulated domain, recorded frame by frame."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.domain.dynamics import ST, wheel_ticks
from proxybench.domain.lane_pose import LP, LanePose
from proxybench.domain.simulator import Simulator

__all__ = ["EpisodeRecord", "PrivilegedAgentError", "run_episode"]


class PrivilegedAgentError(ValueError):
    """A privileged agent (one that reads the true lane pose) was given to a camera-only run."""


@dataclass
class EpisodeRecord:
    """Per-frame arrays of one episode: ``time`` [s], ``pose`` (T, 3) [m, m, rad], ``velocity`` (T, 2)
    [m/s, rad/s], ``lane`` (T, LP.N) lane-pose rows, ``commands`` (T, 2) PWM applied after each frame."""

    time: np.ndarray
    pose: np.ndarray
    velocity: np.ndarray
    lane: np.ndarray
    commands: np.ndarray
    off_road: bool
    meta: dict = field(default_factory=dict)

    def summary(self) -> dict[str, float]:
        """Headline metrics: distance along the lane, lateral error, time in lane, survival."""
        lane = self.lane
        valid = lane[:, LP.VALID] > 0.5
        dt = float(np.diff(self.time).mean()) if len(self.time) > 1 else 0.0
        along = self.velocity[:, 0] * np.cos(np.where(valid, lane[:, LP.HEADING_ERROR], np.pi / 2))
        in_lane = (lane[:, LP.LEFT_IN_LANE] > 0.5) & (lane[:, LP.RIGHT_IN_LANE] > 0.5)
        return {
            "duration_s": float(self.time[-1]) if len(self.time) else 0.0,
            "distance_m": float(np.sum(along[1:]) * dt),
            "mean_abs_lateral_m": float(np.nanmean(np.abs(lane[valid, LP.LATERAL]))) if valid.any() else float("nan"),
            "in_lane_fraction": float(in_lane.mean()) if len(in_lane) else 0.0,
            "off_road": float(self.off_road),
        }


def run_episode(
    sim: Simulator,
    agent: Agent,
    seed: int,
    seconds: float,
    *,
    pose: tuple[float, float, float] | None = None,
    camera: bool = True,
    allow_privileged: bool = True,
    on_frame: Callable[[int, np.ndarray | None, Simulator], None] | None = None,
) -> EpisodeRecord:
    """Drive robot 0 of ``sim`` with ``agent`` for ``seconds`` (or until it leaves the road).

    ``on_frame(k, image, sim)`` is called after each frame (e.g. to write a video). With
    ``allow_privileged=False`` (camera-only evaluation) a privileged agent is refused.
    """
    if agent.privileged and not allow_privileged:
        raise PrivilegedAgentError(
            f"agent {agent.name!r} is privileged (reads the true lane pose); this run allows camera-only agents"
        )
    sim.reset(0, seed, pose)
    agent.reset(seed)
    steps = max(1, round(seconds / sim.frame_dt))
    rows: list[tuple] = []
    for k in range(steps + 1):
        image = sim.render()[0] if camera else None
        s = sim.state[0]
        lp = LanePose.from_row(sim.lane[0]) if agent.privileged else None
        res = sim.params[0].encoder_resolution
        ticks = wheel_ticks(s[[ST.WHEEL_L, ST.WHEEL_R]], res)
        obs = Observation(image, float(sim.time[0]), (float(ticks[0] * res), float(ticks[1] * res)), res, lp)
        if on_frame is not None:
            on_frame(k, image, sim)
        done = k == steps or sim.off_road[0]
        command = np.zeros(2) if done else np.asarray(agent.act(obs), dtype=np.float64).reshape(2)
        rows.append((float(sim.time[0]), s[:3].copy(), s[3:5].copy(), sim.lane[0].copy(), command))
        if done:
            break
        sim.step(command[None])
    t, p, v, lane, c = (np.array(col) for col in zip(*rows, strict=True))
    return EpisodeRecord(t, p, v, lane, c, bool(sim.off_road[0]), {"seed": seed, "agent": agent.name})
