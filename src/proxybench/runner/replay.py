"""Open-loop replays: recorded wheel commands played again in other domains, frame by frame.

Trajectory matching (the system-identification route: which θ reproduces a target's recorded runs under the
same commands?, :mod:`proxybench.experiments.validate.run`) replays each recorded run's commands from its start
(:func:`replay_runs`).

POD (:mod:`proxybench.experiments.predictivity.pod`) compares what two domains' cameras show under one command sequence;
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

__all__ = ["Playback", "agent_commands", "frame_commands", "open_loop_frames", "replay_runs"]


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


class Playback:
    """A batch policy that plays each robot's own command sequence, one row per frame (then zeros)."""

    def __init__(self, commands: Sequence[np.ndarray], name: str = "playback"):
        self.commands = [np.asarray(c, float).reshape(-1, 2) for c in commands]
        self.names = [name] * len(self.commands)
        self.privileged = [False] * len(self.commands)
        self._k = 0

    def reset(self, seeds: Sequence[int]) -> dict[int, BaseException]:
        self._k = 0
        return {}

    def act(self, plant, images, alive: np.ndarray) -> tuple[np.ndarray, dict[int, BaseException]]:
        out = np.array([c[self._k] if self._k < len(c) else (0.0, 0.0) for c in self.commands], float)
        self._k += 1
        return out, {}


def frame_commands(t: np.ndarray, pwm: np.ndarray, frame_rate: float) -> np.ndarray:
    """(frames, 2) wheel commands per frame of a recorded run: the command of the first sample after each frame
    starts (a command recorded at sample j was applied during the step that ends there)."""
    frames = max(1, int(np.floor(t[-1] * frame_rate + 1e-9)))
    idx = np.searchsorted(t, np.arange(frames) / frame_rate, side="right").clip(0, len(t) - 1)
    return np.asarray(pwm, float)[idx]


def replay_runs(m: Map | str, params: DomainParams, runs: Sequence[tuple[np.ndarray, np.ndarray, tuple, int]],
                seconds: float) -> list[np.ndarray]:
    """Replay recorded runs open loop in θ ``params``: each run is (t, pwm (n, 2), start pose, seed); all of them
    one batch of the simulator (no camera). Returns each replay's (samples, 3) array of t, x, y."""
    if not runs:
        return []
    sim = Simulator(m, [params] * len(runs), render=False)
    commands = [frame_commands(t, pwm, 1.0 / sim.frame_dt) for t, pwm, _, _ in runs]
    trajs = rollout(SimPlant(sim), Playback(commands), [seed for *_, seed in runs], seconds,
                    poses=[pose for _, _, pose, _ in runs], camera=False)
    return [np.column_stack([tr["t"], tr["x"], tr["y"]]) for tr in trajs]
