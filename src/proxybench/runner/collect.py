"""Collect behaviour-cloning data with the batched simulator: N robots at once, one compiled step per frame.

Who drives and who labels are separate, as BC practice wants:

- **off-policy (expert) data with recovery**: robots start from perturbed poses (wider lateral offset
  and heading error than evaluation starts) and execute the expert's command *plus* temporally
  correlated noise (noise injection, as in DART), while every frame is labelled with the expert's
  clean command. The data then shows how to get back to the lane centre, which pure expert driving
  never does.
- **on-policy (DAgger) data**: a learner's batched ``policy(images) -> PWM`` drives (optionally mixed
  with the expert with probability ``beta``); the expert still labels every frame.

The expert is pure pursuit on the true lane pose (privileged; only a simulator or a motion-capture lab
knows it). A robot whose episode ends by the engine's rule (``domain.episode_end``: off the road, a
collision), completes ``episode_frames`` or has no valid expert label starts a new episode at once with a
new seed — and, for a domain family, a new θ. (In a simulated domain data collection is a continuing stream
with per-robot resets, not a set of episodes with trajectories, so it steps the batched simulator itself.)

A **robot node** (``Domain.kind == "robot"``: a physical robot's bridge, another simulator, ``proxybench robot
serve``) is driven through the episode engine instead — :func:`~proxybench.runner.rollout.rollout` on its
:class:`~proxybench.runner.robot_episode.RobotPlant`, one episode at a time from the same perturbed starts: the
expert reads the true lane pose the node serves, and its frames are brought to the domain's image size.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import asdict
from typing import Any

import numpy as np

from proxybench import __version__
from proxybench.domain.episode_end import ended
from proxybench.domain.lane_pose import LP
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator, StartDistribution, start_pose
from proxybench.learning.configs import CollectConfig
from proxybench.learning.dataset import ARRAYS, Dataset
from proxybench.learning.domains import Domain
from proxybench.learning.expert import expert_actions
from proxybench.runner.jobs import DomainSpec
from proxybench.runner.plants import PlantPool, fit_frames

__all__ = ["CollectConfig", "Policy", "collect", "episode_seed_for", "lane_rows", "robot_spec"]

#: a batched learner: camera frames (N, H, W, 3) uint8 → wheel PWM (N, 2)
Policy = Callable[[np.ndarray], np.ndarray]


def episode_seed_for(seed: int, episode: int) -> int:
    """The simulator seed of episode ``episode`` of a collection seeded ``seed`` (disjoint from evaluation)."""
    return int(np.random.SeedSequence([seed, episode, 0xB0C]).generate_state(1)[0])


class _Recorder:
    """Grows per-sample arrays and the episode table while the batch runs."""

    def __init__(self, domain: Domain, cfg: CollectConfig):
        self.domain, self.cfg = domain, cfg
        self.rows: dict[str, list[np.ndarray]] = {k: [] for k in ARRAYS}
        self.count = 0
        self.episodes: list[dict[str, Any]] = []
        self.thetas: list[dict[str, Any]] = []
        self._theta_key: dict[str, int] = {}

    def new_episode(self, sim: Simulator | None, robot: int, on_policy: bool) -> int:
        """Start the next episode on ``robot`` of ``sim`` (new seed, new θ for a family); returns its id. Without a
        simulator (a robot node) only the bookkeeping: the caller starts the episode."""
        e = len(self.episodes)
        seed = episode_seed_for(self.cfg.seed, e)
        theta = self.domain.sample(np.random.default_rng(seed))
        if sim is not None:
            if self.domain.space is not None:  # a fixed θ is already the simulator's
                sim.set_params(robot, theta)
            sim.reset(robot, seed)
        key = theta.model_dump_json()
        if key not in self._theta_key:
            self._theta_key[key] = len(self.thetas)
            self.thetas.append(theta.model_dump(mode="json"))
        self.episodes.append({"id": e, "seed": seed, "theta": self._theta_key[key], "robot": robot,
                              "on_policy": on_policy})
        return e

    def add(self, keep: np.ndarray, **arrays: np.ndarray) -> None:
        room = self.cfg.samples - self.count
        idx = np.flatnonzero(keep)[:room]
        for k, v in arrays.items():
            self.rows[k].append(np.asarray(v)[idx])
        self.count += idx.size

    def dataset(self, extra_meta: dict[str, Any]) -> Dataset:
        arrays = {k: np.concatenate(v) if v else np.zeros((0,)) for k, v in self.rows.items()}
        order = np.lexsort((arrays["frame"], arrays["episode"]))  # episode by episode
        arrays = {k: v[order].astype(ARRAYS[k][0]) for k, v in arrays.items()}
        used = set(np.unique(arrays["episode"]).tolist())
        meta = {"domain": self.domain.describe(), "collect": asdict(self.cfg), "proxybench_version": __version__,
                "episodes": [e for e in self.episodes if e["id"] in used], "thetas": self.thetas, **extra_meta}
        return Dataset(arrays, meta)


def _roomiest(base: DomainParams) -> DomainParams:
    """θ needing the deepest command and pose histories any θ can need.

    A simulator sizes its history rings for the robots it is built with and, when a later θ needs more,
    regrows them for *every* robot, restarting their histories mid-episode. Building the batch with this
    θ first means no draw from a family ever triggers that (every robot gets its real θ before stepping).
    """
    return base.replace(command_delay=2.0, delay_jitter=1.0, blur_time=1.0, blur_samples=32)  # DomainParams' bounds


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
    if domain.kind == "robot":
        with contextlib.ExitStack() as stack:
            pool = pool or stack.enter_context(PlantPool())
            return _collect_on_robot(pool.robot(robot_spec(domain), cfg.map), domain, cfg, policy, beta, progress)
    base = domain.base
    start = StartDistribution(lateral=cfg.start_lateral, heading=cfg.start_heading, use_map_start=False)
    first = base if domain.space is None else _roomiest(base)
    sim = Simulator(cfg.map, [first] + [base] * (cfg.robots - 1), start=start)
    rec = _Recorder(domain, cfg)
    on_policy = policy is not None
    episode = np.array([rec.new_episode(sim, i, on_policy) for i in range(cfg.robots)], dtype=np.int64)
    rng = np.random.default_rng([cfg.seed, 0x5EED])
    noise = np.zeros((cfg.robots, 2))
    innov = cfg.noise_std * np.sqrt(1.0 - cfg.noise_corr ** 2)
    while rec.count < cfg.samples:
        images = sim.render()
        labels = expert_actions(sim.lane)
        valid = sim.lane[:, LP.VALID] > 0.5
        if policy is None:
            executed = labels + noise
            noise = cfg.noise_corr * noise + innov * rng.standard_normal(noise.shape)
        else:
            learner = np.asarray(policy(images), dtype=np.float64).reshape(cfg.robots, 2)
            executed = np.where((rng.random(cfg.robots) < beta)[:, None], labels, learner)
        executed = np.clip(executed, -1.0, 1.0)
        rec.add(valid, images=images, actions=labels, executed=executed, episode=episode.copy(),
                frame=sim.frame_index.copy(), on_policy=np.full(cfg.robots, on_policy))
        sim.step(executed)
        done = ended(sim) | (sim.frame_index >= cfg.episode_frames) | ~valid
        for i in np.flatnonzero(done):
            episode[i] = rec.new_episode(sim, int(i), on_policy)
            noise[i] = 0.0
        if progress:
            progress(min(rec.count, cfg.samples), cfg.samples)
    return rec.dataset({"beta": beta if on_policy else None})


def robot_spec(domain: Domain) -> DomainSpec:
    """The runner's spec of a robot domain (its node, stepped at the domain's frame rate)."""
    return DomainSpec.robot(domain.command, frame_rate=domain.frame_rate)


def lane_rows(plant: Any) -> np.ndarray:
    """(N, LP.N) true lane-pose rows of a plant's robots: the simulator's array, or what a robot node serves
    (a row that is not valid where it serves none)."""
    sim = getattr(plant, "sim", None)
    if sim is not None:
        return sim.lane[: plant.n]
    rows = np.zeros((plant.n, LP.N))
    for i in range(plant.n):
        lp = plant.observation(i, None, True).lane_pose
        if lp is not None:
            rows[i] = lp.to_row()
    return rows


class _NoLabel(RuntimeError):
    """Ends a collection episode: the expert has no label here, or the data set is full."""


class _RobotDriver:
    """The episode engine's policy for collecting on a robot node: the noisy expert or the learner drives, the
    expert labels, and every frame with a valid label is recorded."""

    def __init__(self, rec: _Recorder, episode: int, size: tuple[int, int], policy: Policy | None, beta: float,
                 rng: np.random.Generator):
        self.privileged = [True]  # the expert reads the true lane pose
        self.rec, self.episode, self.size, self.policy, self.beta, self.rng = rec, episode, size, policy, beta, rng
        self.names = ["learner" if policy is not None else "expert"]
        self.noise, self.k = np.zeros(2), 0

    def reset(self, seeds) -> dict[int, BaseException]:
        return {}

    def act(self, plant: Any, images: Any, alive: np.ndarray) -> tuple[np.ndarray, dict[int, BaseException]]:
        cfg = self.rec.cfg
        lane = lane_rows(plant)
        if lane[0, LP.VALID] <= 0.5 or images is None or images[0] is None or self.rec.count >= cfg.samples:
            return np.zeros((1, 2)), {0: _NoLabel("no expert label (off every lane), or the data set is full")}
        frame = fit_frames(np.asarray(images[0])[None], self.size)
        label = expert_actions(lane)
        if self.policy is None:
            executed = label + self.noise
            innov = cfg.noise_std * np.sqrt(1.0 - cfg.noise_corr ** 2)
            self.noise = cfg.noise_corr * self.noise + innov * self.rng.standard_normal(2)
        else:
            learner = np.asarray(self.policy(frame), dtype=np.float64).reshape(1, 2)
            executed = label if self.rng.random() < self.beta else learner
        executed = np.clip(executed, -1.0, 1.0)
        self.rec.add(np.array([True]), images=frame, actions=label, executed=executed, episode=[self.episode],
                     frame=[self.k], on_policy=[self.policy is not None])
        self.k += 1
        return executed, {}


def _collect_on_robot(plant: Any, domain: Domain, cfg: CollectConfig, policy: Policy | None, beta: float,
                      progress: Callable[[int, int], None] | None) -> Dataset:
    """Episodes of ``cfg.episode_frames`` frames, one after another, on a robot node, through the episode engine."""
    from proxybench.runner.rollout import rollout

    rec = _Recorder(domain, cfg)
    rng = np.random.default_rng([cfg.seed, 0x5EED])
    start = StartDistribution(lateral=cfg.start_lateral, heading=cfg.start_heading, use_map_start=False)
    empty = 0
    while rec.count < cfg.samples:
        before = rec.count
        seconds = cfg.episode_frames / _rate(plant, domain.frame_rate)  # a node may step at its own rate
        e = rec.new_episode(None, 0, policy is not None)
        seed = rec.episodes[e]["seed"]
        rollout(plant, _RobotDriver(rec, e, domain.image_size, policy, beta, rng), [seed], seconds,
                poses=[start_pose(plant.map, seed, start)])
        if progress:
            progress(min(rec.count, cfg.samples), cfg.samples)
        empty = empty + 1 if rec.count == before else 0
        if empty >= 20:
            raise RuntimeError(f"{domain.name}: no labelled frame in 20 episodes in a row: the node serves no true "
                               "lane pose, or every start is off the lanes")
    return rec.dataset({"beta": beta if policy is not None else None})


def _rate(plant: Any, asked: float) -> float:
    """The rate a robot node steps at: what it said when its last episode began, else what it is asked."""
    try:
        return float(plant.frame_rate)
    except AttributeError:  # no episode yet
        return asked
