"""Open-loop replays: the same wheel commands played in several domains side by side, frame by frame.

POD (:mod:`proxybench.experiments.pod`) compares what two domains' cameras show under one command sequence;
the commands themselves come from an agent driving one of them (:func:`agent_commands`). Both are episodes
of the one engine (:func:`~proxybench.runner.rollout.rollout`): the domains are one batch of the simulator,
so their frames are rendered in one call and the engine's ending rule applies.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from proxybench.domain.maps import Map
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator
from proxybench.runner.episode import SimPlant, run_episode
from proxybench.runner.rollout import OpenLoopPolicy, rollout

__all__ = ["agent_commands", "open_loop_frames"]


def open_loop_frames(
    m: Map | str, thetas: Sequence[DomainParams], commands: np.ndarray, on_frames: Callable[[list[np.ndarray]], None],
    *, seed: int = 0, pose: tuple[float, float, float] | None = None,
) -> None:
    """Play ``commands`` (T, 2) PWM open loop in every domain θ of ``thetas`` from one start pose (drawn from
    ``seed`` if not given); ``on_frames(images)`` gets the frames of every domain while no episode has ended."""
    commands = np.asarray(commands, dtype=float).reshape(-1, 2)
    if not len(commands):
        return
    sim = Simulator(m, list(thetas))
    if pose is None:
        pose = sim.sample_start(np.random.default_rng(seed))
    n = len(thetas)

    def hook(k: int, images, alive: np.ndarray, plant: SimPlant) -> None:
        if alive.all():
            on_frames(list(images))

    rollout(SimPlant(sim), OpenLoopPolicy(commands, n), [seed] * n, len(commands) * sim.frame_dt, poses=[pose] * n,
            on_frame=hook)


def agent_commands(m: Map | str, params: DomainParams, agent, seed: int, seconds: float) -> np.ndarray:
    """The wheel commands (frames, 2) ``agent`` issues per camera frame driving from ``seed``'s start in θ."""
    sim = Simulator(m, params, render=False)
    traj = run_episode(sim, agent, seed, seconds, camera=False)
    per_frame = sim.substeps
    return np.stack([traj["pwm_left"][1::per_frame], traj["pwm_right"][1::per_frame]], axis=1)
