"""An auto-resetting plant: a robot whose episode ends starts its next one at once, and the stream goes on.

Behaviour-cloning data collection is a continuing stream of frames, not a set of episodes with trajectories:
each robot of the batch restarts (next start, next seed, for a domain family next θ) as soon as its episode
ends, while the others drive on. As Gymnasium's and Brax's auto-reset, that is a wrapper of a plant, and the
stream is the episode engine's own loop (:func:`~proxybench.runner.rollout.stream`, one frame exactly as
:func:`~proxybench.runner.rollout.rollout` plays it), driven by any policy of the engine.

A robot's episode ends when its driver fails (e.g. a labelling expert with no label), when the plant says so
(collision, off the road: ``domain.episode_end``; a robot node's own report), or when its frames are spent.
Where it restarts comes from ``next_start(robot)``, asked once per episode in the order episodes begin (at the
start robot 0, 1, …; then, after each frame, the robots whose episodes ended, in robot order), so episode numbers
and seeds follow from that order alone.

Inner plants: a :class:`~proxybench.runner.episode.SimPlant` built with ``trace=False`` (:func:`sim_stream`),
whose robots restart one by one in the running batch, or any plant of one robot (a robot node's
:class:`~proxybench.runner.robot_episode.RobotPlant`), whose episode is ended and begun again.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from proxybench.domain.maps import Map
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator, StartDistribution
from proxybench.runner.episode import SimPlant
from proxybench.runner.rollout import Plant
from proxybench.tasks.trajectory import Event

__all__ = ["AutoResetPlant", "Start", "sim_stream"]


@dataclass(frozen=True)
class Start:
    """Where a robot's next episode starts: its seed, θ (None: the robot's own) and pose (None: drawn from the
    seed by the plant's start distribution)."""

    seed: int
    params: DomainParams | None = None
    pose: tuple[float, float, float] | None = None


class AutoResetPlant:
    """``plant`` with auto-reset: episodes of at most ``episode_frames`` frames, each robot restarting from
    ``next_start(robot)`` when its episode ended (see the module). ``frame_rate``: the rate to ask for while the
    inner plant does not know its own (a robot node says it when its first episode begins).

    ``episode`` (N,): the number of the episode each robot is in (0, 1, … in the order they began); ``frame`` (N,):
    frames into it; ``starts``: every episode begun, as (robot, :class:`Start`), indexed by episode number.
    """

    def __init__(self, plant: Plant, next_start: Callable[[int], Start], episode_frames: int, *,
                 frame_rate: float = 15.0):
        if episode_frames < 1:
            raise ValueError(f"episode_frames must be positive, got {episode_frames}")
        self.inner = plant
        self.n = plant.n
        self.map: Map = plant.map
        self.sim = getattr(plant, "sim", None)  # the simulator's arrays, for what reads them (``lane_rows``)
        self.next_start = next_start
        self.episode_frames = episode_frames
        self.asked_rate = frame_rate
        self.batch = hasattr(plant, "restart")  # robots restart one by one in the running batch
        if not self.batch and self.n != 1:
            raise ValueError(f"a plant of {self.n} robots restarts robots one by one (SimPlant.restart); "
                             f"{type(plant).__name__} does not")
        self.episode = np.full(self.n, -1, dtype=np.int64)
        self.frame = np.zeros(self.n, dtype=np.int64)
        self.limit = np.full(self.n, episode_frames, dtype=np.int64)
        self.starts: list[tuple[int, Start]] = []

    @property
    def frame_rate(self) -> float:
        """[Hz] the inner plant's frame rate, or the one asked for while it knows none."""
        try:
            return float(self.inner.frame_rate)
        except AttributeError:  # a robot node before its first episode
            return self.asked_rate

    def _next(self, i: int) -> Start:
        start = self.next_start(i)
        if start.params is not None and not self.batch:
            raise ValueError(f"{type(self.inner).__name__}'s θ is its own: a start cannot set it")
        self.episode[i], self.frame[i] = len(self.starts), 0
        self.starts.append((i, start))
        return start

    def open(self, camera: bool, privileged: Sequence[bool]) -> list[int]:
        """Every robot's first episode (robot 0 first); their seeds."""
        self.camera, self.privileged = camera, list(privileged)
        starts = [self._next(i) for i in range(self.n)]
        for i, s in enumerate(starts):
            if s.params is not None:
                self.inner.set_params(i, s.params)
        self._begin([s.seed for s in starts], [s.pose for s in starts])
        return [s.seed for s in starts]

    def _begin(self, seeds: list[int], poses: list[Any]) -> None:
        seconds = self.episode_frames / self.frame_rate
        steps = self.inner.begin(seeds, poses, [None] * self.n, seconds, self.camera, self.privileged)
        self.limit[:] = steps if not self.batch else self.episode_frames

    def _restart(self, i: int) -> None:
        s = self._next(i)
        if not self.batch:
            self.inner.end()
            self._begin([s.seed], [s.pose])
            return
        if s.params is not None:
            self.inner.set_params(i, s.params)
        self.inner.restart(i, s.seed, s.pose)

    # the engine's side: a plant

    def begin(self, seeds: Sequence[int], poses: Sequence[Any], routes: Sequence[Any], seconds: float,
              camera: bool, privileged: Sequence[bool]) -> int:
        raise TypeError("an auto-resetting plant starts its own episodes: play it with rollout.stream, not rollout")

    def frames(self, alive: np.ndarray) -> Any:
        return self.inner.frames(alive)

    def observation(self, i: int, image: np.ndarray | None, privileged: bool) -> Any:
        return self.inner.observation(i, image, privileged)

    def time(self, i: int) -> float:
        return self.inner.time(i)

    def advance(self, commands: np.ndarray, alive: np.ndarray, k: int) -> list[tuple[int, Event, bool]]:
        """Advance the running robots one frame; then restart, in robot order, every robot whose episode ended:
        its driver failed (not ``alive``), the plant ended it, or its frames are spent. The plant's events come
        back none of them final (the stream goes on)."""
        happened = self.inner.advance(commands, alive, int(self.frame[0])) if alive.any() else []
        ended = ~alive
        for i, _, final in happened:
            ended[i] |= final
        self.frame[alive] += 1
        ended |= self.frame >= self.limit
        for i in np.flatnonzero(ended):
            self._restart(int(i))
        return [(i, event, False) for i, event, _ in happened]

    def end(self) -> None:
        self.inner.end()


def sim_stream(map_: Map | str, base: DomainParams, n: int, start: StartDistribution, *,
               varying: bool = False) -> SimPlant:
    """A batched simulator of ``n`` robots of θ ``base`` as the inner plant of an :class:`AutoResetPlant` (no
    physics-rate record, the renderer's frames as they are), episodes starting from ``start``.

    ``varying``: θ will change per episode (a domain family). A simulator sizes its history rings for the robots it
    is built with and, when a later θ needs more, regrows them for *every* robot, restarting their histories
    mid-episode; building the batch with the roomiest θ first means no draw ever triggers that (every robot gets
    its real θ before it steps).
    """
    first = base.replace(command_delay=2.0, delay_jitter=1.0, blur_time=1.0, blur_samples=32) if varying else base
    return SimPlant(Simulator(map_, [first] + [base] * (n - 1), start=start), trace=False)
