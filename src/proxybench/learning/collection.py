"""Collect behaviour-cloning data: N robots at once, a continuing stream, through the episode engine.

Who drives and who labels are separate, as BC practice wants:

- **off-policy (expert) data with recovery**: robots start from perturbed poses (wider lateral offset
  and heading error than evaluation starts) and execute the expert's command *plus* temporally
  correlated noise (noise injection, as in DART), while every frame is labelled with the expert's
  clean command. The data then shows how to get back to the lane centre, which pure expert driving
  never does.
- **on-policy (DAgger) data**: a learner's batched ``policy(images) -> PWM`` drives (optionally mixed
  with the expert with probability ``beta``); the expert still labels every frame.

The expert is pure pursuit on the true lane pose (privileged; only a simulator, a robot node that serves it or a
motion-capture lab knows it). Data collection is a continuing stream with per-robot resets: the runner's
auto-resetting plant (:class:`~proxybench.runner.autoreset.AutoResetPlant`) under the engine's loop
(:func:`~proxybench.runner.rollout.stream`), driven by :class:`ExpertMix`, a batched policy of the engine. A robot
whose episode ends by the engine's rule (``domain.episode_end``: off the road, a collision; a robot node's own
report), completes ``episode_frames`` or has no valid expert label (its driver fails) starts a new episode at
once with a new seed — and, for a domain family, a new θ.

In a simulated domain the N robots are one batched simulator; a **robot node** (``Domain.kind == "robot"``: a
physical robot's bridge, another simulator, ``proxybench robot serve``) is one robot whose episodes follow one
another from the same perturbed starts: the expert reads the true lane pose the node serves, and its frames are
brought to the domain's image size.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import numpy as np

from proxybench import __version__
from proxybench.domain.lane_pose import LP
from proxybench.domain.simulator import StartDistribution, start_pose
from proxybench.learning.configs import CollectConfig
from proxybench.learning.dataset import ARRAYS, Dataset
from proxybench.learning.domains import Domain
from proxybench.learning.expert import expert_actions
from proxybench.runner.autoreset import AutoResetPlant, Start, sim_stream
from proxybench.runner.jobs import DomainSpec
from proxybench.runner.plants import PlantPool, fit_frames
from proxybench.runner.rollout import BatchPolicy, Plant, lane_rows, stream

__all__ = ["CollectConfig", "ExpertMix", "Policy", "collect", "episode_seed_for", "robot_spec"]

#: a batched learner: camera frames (N, H, W, 3) uint8 → wheel PWM (N, 2)
Policy = Callable[[np.ndarray], np.ndarray]


def episode_seed_for(seed: int, episode: int) -> int:
    """The simulator seed of episode ``episode`` of a collection seeded ``seed`` (disjoint from evaluation)."""
    return int(np.random.SeedSequence([seed, episode, 0xB0C]).generate_state(1)[0])


def robot_spec(domain: Domain) -> DomainSpec:
    """The runner's spec of a robot domain (its node, stepped at the domain's frame rate)."""
    return DomainSpec.robot(domain.command, frame_rate=domain.frame_rate)


class _Recorder:
    """Grows per-sample arrays and the episode table while the stream runs; the plant's ``next_start``."""

    def __init__(self, domain: Domain, cfg: CollectConfig, on_policy: bool, poses: Plant | None):
        self.domain, self.cfg, self.on_policy = domain, cfg, on_policy
        self.start = StartDistribution(lateral=cfg.start_lateral, heading=cfg.start_heading, use_map_start=False)
        self.poses = poses  # a robot node is told where its robot stands; a simulator draws it from the seed
        self.rows: dict[str, list[np.ndarray]] = {k: [] for k in ARRAYS}
        self.count = 0
        self.episodes: list[dict[str, Any]] = []
        self.thetas: list[dict[str, Any]] = []
        self._theta_key: dict[str, int] = {}
        self._empty, self._count_then = 0, 0

    def __call__(self, robot: int) -> Start:
        """The next episode, on ``robot``: its seed, θ (a family's draw) and, on a robot node, its start pose."""
        e = len(self.episodes)
        if self.poses is not None and e:
            self._empty = self._empty + 1 if self.count == self._count_then else 0
            self._count_then = self.count
            if self._empty >= 20:
                raise RuntimeError(f"{self.domain.name}: no labelled frame in 20 episodes in a row: the node serves "
                                   "no true lane pose, or every start is off the lanes")
        seed = episode_seed_for(self.cfg.seed, e)
        theta = self.domain.sample(np.random.default_rng(seed))
        key = theta.model_dump_json()
        if key not in self._theta_key:
            self._theta_key[key] = len(self.thetas)
            self.thetas.append(theta.model_dump(mode="json"))
        self.episodes.append({"id": e, "seed": seed, "theta": self._theta_key[key], "robot": robot,
                              "on_policy": self.on_policy})
        pose = None if self.poses is None else start_pose(self.poses.map, seed, self.start)
        return Start(seed, theta if self.domain.space is not None else None, pose)  # a fixed θ is the plant's

    def add(self, keep: np.ndarray, **arrays: np.ndarray) -> None:
        room = self.cfg.samples - self.count
        idx = np.flatnonzero(keep)[:room]
        for k, v in arrays.items():
            self.rows[k].append(np.asarray(v)[idx])
        self.count += idx.size

    def full(self) -> bool:
        return self.count >= self.cfg.samples

    def dataset(self, extra_meta: dict[str, Any]) -> Dataset:
        arrays = {k: np.concatenate(v) if v else np.zeros((0,)) for k, v in self.rows.items()}
        order = np.lexsort((arrays["frame"], arrays["episode"]))  # episode by episode
        arrays = {k: v[order].astype(ARRAYS[k][0]) for k, v in arrays.items()}
        used = set(np.unique(arrays["episode"]).tolist())
        meta = {"domain": self.domain.describe(), "collect": asdict(self.cfg), "proxybench_version": __version__,
                "episodes": [e for e in self.episodes if e["id"] in used], "thetas": self.thetas, **extra_meta}
        return Dataset(arrays, meta)


class _NoLabel(RuntimeError):
    """Ends a robot's collection episode: the expert has no label here (off every lane), or there is no frame."""


class ExpertMix(BatchPolicy):
    """The engine's batched policy of data collection: the noisy expert (``policy`` None) or the learner drives
    (the expert instead with probability ``beta`` per robot and frame), the expert labels, and every frame with a
    valid label is recorded. A robot without a label fails (its episode ends; the plant restarts it).

    Randomness: one generator seeded (seed, 0x5EED); each frame in which some robot has a label draws the whole
    batch's noise (N, 2) (off-policy: AR(1), zeroed when a robot's episode begins) or mixing coins (N,).
    """

    def __init__(self, rec: _Recorder, n: int, size: tuple[int, int], policy: Policy | None, beta: float,
                 progress: Callable[[int, int], None] | None):
        super().__init__(self._commands, n, "learner" if policy is not None else "expert", privileged=True)
        self.rec, self.size, self.policy, self.beta, self.progress = rec, size, policy, beta, progress
        cfg = rec.cfg
        self.rng = np.random.default_rng([cfg.seed, 0x5EED])
        self.noise = np.zeros((n, 2))
        self.innov = cfg.noise_std * np.sqrt(1.0 - cfg.noise_corr ** 2)
        self.episode = np.full(n, -1, dtype=np.int64)

    def act(self, plant: Any, images: Any, alive: np.ndarray) -> tuple[np.ndarray, dict[int, BaseException]]:
        self.lane = lane_rows(plant)
        seen = np.array([images is not None and images[i] is not None for i in range(self.n)])
        self.valid = (self.lane[:, LP.VALID] > 0.5) & seen
        failed = {int(i): _NoLabel("no expert label (off every lane), or no camera frame")
                  for i in np.flatnonzero(~self.valid)}
        if not self.valid.any():  # nobody acts: nothing drawn, nothing recorded
            return np.zeros((self.n, 2)), failed
        return super().act(plant, images, alive)[0], failed

    def _commands(self, images: Any, plant: Any) -> np.ndarray:
        """The executed commands of every robot; the frame's labelled samples recorded."""
        new = plant.episode != self.episode  # robots whose episode began since the last frame
        self.noise[new] = 0.0
        self.episode = plant.episode.copy()
        cfg = self.rec.cfg
        frames = images if isinstance(images, np.ndarray) else np.stack(
            [np.zeros((self.size[1], self.size[0], 3), np.uint8) if f is None else np.asarray(f) for f in images])
        frames = fit_frames(frames, self.size)
        labels = expert_actions(self.lane)
        if self.policy is None:
            executed = labels + self.noise
            self.noise = cfg.noise_corr * self.noise + self.innov * self.rng.standard_normal(self.noise.shape)
        else:
            learner = np.asarray(self.policy(frames), dtype=np.float64).reshape(self.n, 2)
            executed = np.where((self.rng.random(self.n) < self.beta)[:, None], labels, learner)
        executed = np.clip(executed, -1.0, 1.0)
        self.rec.add(self.valid, images=frames, actions=labels, executed=executed, episode=plant.episode.copy(),
                     frame=plant.frame.copy(), on_policy=np.full(self.n, self.policy is not None))
        if self.progress:
            self.progress(min(self.rec.count, cfg.samples), cfg.samples)
        return executed


def collect(
    domain: Domain,
    cfg: CollectConfig,
    policy: Policy | None = None,
    beta: float = 0.0,
    progress: Callable[[int, int], None] | None = None,
    pool: PlantPool | None = None,
) -> Dataset:
    """Record ``cfg.samples`` labelled frames in ``domain``.

    Without ``policy`` the noisy expert drives (off-policy data); with one, the learner drives and the
    expert's command is executed instead with probability ``beta`` per frame (DAgger's mixture).
    Frames where the robot is off every lane (no valid expert label) are not recorded. A robot domain's node
    comes from ``pool`` (kept running there), else is started for this call.
    """
    if not 0.0 <= beta <= 1.0:
        raise ValueError(f"beta must be in [0, 1], got {beta}")
    on_policy = policy is not None
    with contextlib.ExitStack() as stack:
        if domain.kind == "robot":
            inner: Plant = (pool or stack.enter_context(PlantPool())).robot(robot_spec(domain), cfg.map)
            rec = _Recorder(domain, cfg, on_policy, poses=inner)
        else:
            rec = _Recorder(domain, cfg, on_policy, poses=None)
            inner = sim_stream(cfg.map, domain.base, cfg.robots, rec.start, varying=domain.space is not None)
        plant = AutoResetPlant(inner, rec, cfg.episode_frames, frame_rate=domain.frame_rate)
        stream(plant, ExpertMix(rec, plant.n, domain.image_size, policy, beta, progress), rec.full)
    return rec.dataset({"beta": beta if on_policy else None})
