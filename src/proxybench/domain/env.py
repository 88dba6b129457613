"""Gymnasium envs: ``proxybench/LaneFollowing-v0`` and its batched vector form.

Both are thin layers over ``Simulator``; the vector env steps all N robots in one compiled call per
frame (no Python loop over robots), and robot i of a vector env reset with seed s behaves exactly as a
single env reset with seed s + i (tested).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from proxybench.domain.dynamics import ST
from proxybench.domain.env_render import RENDER_MODES, EnvView, check_render_args, view_frame
from proxybench.domain.episode_end import ended
from proxybench.domain.lane_pose import LANE_POSE_FIELDS, LP, LanePose
from proxybench.domain.maps import Map
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator, StartDistribution
from proxybench.domain.topdown import top_down

__all__ = ["RENDER_MODES", "LaneFollowingEnv", "LaneFollowingVectorEnv", "RewardWeights", "lane_following_reward"]

VECTOR_RENDER_MODES = ["rgb_array"]
OBSERVATIONS = ("camera", "state")


@dataclass(frozen=True)
class RewardWeights:
    """Weights of the named reward terms (each term is reported in ``info["reward_terms"]``).

    progress = ``progress`` × v cos(heading error) [m/s]; lateral = −``lateral`` × |offset| [m];
    heading = −``heading`` × |heading error| [rad]; off_road = −``off_road`` once, on leaving the road or
    hitting an object of the map.
    """

    progress: float = 1.0
    lateral: float = 2.0
    heading: float = 0.5
    off_road: float = 10.0


def lane_following_reward(
    state: np.ndarray, lane: np.ndarray, off_road: np.ndarray, w: RewardWeights
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Per-robot reward (N,) and its named terms from simulator arrays."""
    valid = lane[:, LP.VALID] > 0.5
    herr = np.where(valid, lane[:, LP.HEADING_ERROR], 0.0)
    lat = np.where(valid, lane[:, LP.LATERAL], 0.0)
    terms = {
        "progress": w.progress * state[:, ST.V] * np.cos(herr) * valid,
        "lateral": -w.lateral * np.abs(lat),
        "heading": -w.heading * np.abs(herr),
        "off_road": -w.off_road * off_road.astype(np.float64),
    }
    return sum(terms.values()), terms


def _observation_space(p: DomainParams, observation: str) -> spaces.Box:
    if observation == "camera":
        return spaces.Box(0, 255, (p.image_height, p.image_width, 3), dtype=np.uint8)
    if observation == "state":  # lateral [m], heading error [rad], v [m/s], ω [rad/s]
        high = np.array([1.0, np.pi, 5.0, 100.0], dtype=np.float32)
        return spaces.Box(-high, high, dtype=np.float32)
    raise ValueError(f"observation must be one of {OBSERVATIONS}, got {observation!r}")


class _Core:
    """What the single and the vector env share: the simulator, spaces, reward and info."""

    def __init__(self, map: Map | str, params: Any, n: int, observation: str, episode_seconds: float,
                 reward: RewardWeights | None, start: StartDistribution | None):
        plist = params if isinstance(params, (list, tuple)) else [params] * n
        plist = [p if isinstance(p, DomainParams) else DomainParams.model_validate(p or {}) for p in plist]
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {OBSERVATIONS}, got {observation!r}")
        if episode_seconds <= 0:
            raise ValueError(f"episode_seconds must be positive, got {episode_seconds}")
        self.observation = observation
        self.sim = Simulator(map, plist, render=observation == "camera", start=start)
        self.weights = reward or RewardWeights()
        self.max_steps = max(1, round(episode_seconds * plist[0].frame_rate))
        self.obs_space = _observation_space(plist[0], observation)

    def observe(self) -> np.ndarray:
        if self.observation == "camera":
            return self.sim.render()
        s, lane = self.sim.state, self.sim.lane
        box = self.obs_space
        return np.clip(np.stack(
            [np.nan_to_num(lane[:, LP.LATERAL]), np.nan_to_num(lane[:, LP.HEADING_ERROR]), s[:, ST.V], s[:, ST.OMEGA]],
            axis=1,
        ).astype(np.float32), box.low, box.high)

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Advance all robots; (reward, terminated, truncated). The episode-end rule (``domain.episode_end``:
        off the road, a collision) terminates; ``episode_seconds`` truncates."""
        was_out = ended(self.sim)
        self.sim.step(actions)
        out = ended(self.sim)
        reward, self.terms = lane_following_reward(self.sim.state, self.sim.lane, out & ~was_out, self.weights)
        truncated = (self.sim.frame_index >= self.max_steps) & ~out
        return reward, out, truncated  # ``out`` is a new array: the caller may keep it


def _info_one(core: _Core, i: int) -> dict[str, Any]:
    sim = core.sim
    s = sim.state[i]
    lp = LanePose.from_row(sim.lane[i])
    info: dict[str, Any] = {
        "pose": s[:3].copy(),
        "velocity": s[3:5].copy(),
        "lane_pose": lp,
        "wheels_in_lane": np.array([lp.left_in_lane, lp.right_in_lane]),
        "on_road": lp.on_road,
        "collision": bool(sim.collided[i]),
        "time": float(sim.frame_index[i] * sim.frame_dt),  # ``sim.time[i]`` without the (N,) array
    }
    if hasattr(core, "terms"):
        info["reward_terms"] = {k: float(v[i]) for k, v in core.terms.items()}
    return info


class LaneFollowingEnv(gym.Env):
    """Drive a Duckiebot in the right lane of a Duckietown map, from its camera.

    ## Description
    One DB18 robot on a tiled map (default: the 3×3 loop). Everything about the world, from wheel trim
    and command delay to camera pitch and light, is a field of ``DomainParams``.

    ## Action space
    ``Box(-1, 1, (2,), float32)``: wheel PWM (left, right).

    ## Observation space
    ``observation="camera"``: ``Box(0, 255, (H, W, 3), uint8)`` camera frame (H, W from the params, 480×640
    by default). ``observation="state"``: ``[lateral offset m, heading error rad, v m/s, ω rad/s]`` float32.

    ## Rewards
    Per frame: v cos(heading error) − 2 |lateral offset| − 0.5 |heading error|, and −10 on leaving the road
    (``RewardWeights``); each term is in ``info["reward_terms"]``.

    ## Starting state
    A random point of a random lane (offset ±4 cm, heading ±0.35 rad), or the map's ``start_pose``.
    ``reset(options={"pose": (x, y, θ)})`` starts at a given pose.

    ## Episode end
    Terminated when the robot centre leaves the drivable area or comes too close to a map object
    (0.10 m from a duckie, 0.15 m from a robot); truncated after ``episode_seconds``.

    ## Rendering
    ``render_mode`` ``"rgb_array"`` or ``"human"`` (a window; needs a screen), and ``"rgb_array_list"``
    through ``gymnasium.make``; ``render_view`` ``"camera"``, ``"top_down"`` or ``"both"``
    (``proxybench.domain.env_render``). Randomise θ per episode with
    ``proxybench.domain.randomization.DomainRandomization``.

    ## Arguments
    ``map`` (name or ``Map``), ``params`` (``DomainParams`` or dict), ``observation``, ``episode_seconds``
    (60), ``reward`` (``RewardWeights``), ``start`` (``StartDistribution``), ``render_mode``, ``render_view``.
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": RENDER_MODES, "render_fps": 15}

    def __init__(
        self,
        map: Map | str = "loop_3x3",
        params: DomainParams | dict | None = None,
        observation: str = "camera",
        episode_seconds: float = 60.0,
        reward: RewardWeights | None = None,
        start: StartDistribution | None = None,
        render_mode: str | None = None,
        render_view: str = "camera",
    ):
        check_render_args(render_mode, render_view)
        self._core = _Core(map, params, 1, observation, episode_seconds, reward, start)
        self.render_mode = render_mode
        self._view = EnvView(render_mode, render_view, self._core.sim.params[0].frame_rate)
        self.observation_space = self._core.obs_space
        self.action_space = spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
        self.metadata = {**self.metadata, "render_fps": self.params.frame_rate}
        self._obs: np.ndarray | None = None

    @property
    def sim(self) -> Simulator:
        return self._core.sim

    @property
    def params(self) -> DomainParams:
        return self._core.sim.params[0]

    def set_params(self, params: DomainParams) -> None:
        """Change θ; takes effect at the next reset."""
        self._pending = params

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        episode = seed if seed is not None else int(self.np_random.integers(2**63))
        if getattr(self, "_pending", None) is not None:
            self.sim.set_params(0, self._pending)
            self._pending = None
        pose = (options or {}).get("pose")
        self.sim.reset(0, episode, None if pose is None else tuple(float(v) for v in pose))
        self._core.__dict__.pop("terms", None)
        self._obs = self._core.observe()[0]
        self._view.after_update(self.sim, self._camera())
        return self._obs, _info_one(self._core, 0)

    def step(self, action):
        reward, term, trunc = self._core.step(np.asarray(action, dtype=np.float64).reshape(1, 2))
        self._obs = self._core.observe()[0]
        self._view.after_update(self.sim, self._camera())
        return self._obs, float(reward[0]), bool(term[0]), bool(trunc[0]), _info_one(self._core, 0)

    def _camera(self) -> np.ndarray | None:
        return self._obs if self._core.observation == "camera" else None

    def render(self):
        return self._view.render(self.sim, self._camera())

    def close(self):
        self._view.close()
        super().close()


class LaneFollowingVectorEnv(VectorEnv):
    """N lane-following robots stepped together (next-step autoreset, as Gymnasium's vector envs).

    Arguments as :class:`LaneFollowingEnv`, plus ``num_envs``; ``params`` may be one ``DomainParams``
    or a list of N (structural fields such as the image size must agree). ``info`` holds arrays:
    ``pose`` (N, 3), ``velocity`` (N, 2), ``lane_pose`` (N, len(LANE_POSE_FIELDS)), ``on_road`` (N,),
    ``time`` (N,) and ``reward_terms``. ``render()`` (``render_mode="rgb_array"``) returns every robot's frame
    (N, H, W, 3) for ``render_view`` ``"camera"`` or ``"both"``, and one map with all robots for ``"top_down"``.
    """

    metadata: ClassVar[dict[str, Any]] = {
        "render_modes": VECTOR_RENDER_MODES, "render_fps": 15, "autoreset_mode": AutoresetMode.NEXT_STEP
    }

    def __init__(
        self,
        num_envs: int = 8,
        map: Map | str = "loop_3x3",
        params: DomainParams | dict | list | None = None,
        observation: str = "camera",
        episode_seconds: float = 60.0,
        reward: RewardWeights | None = None,
        start: StartDistribution | None = None,
        render_mode: str | None = None,
        render_view: str = "camera",
    ):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        check_render_args(render_mode, render_view, VECTOR_RENDER_MODES)
        self._core = _Core(map, params, num_envs, observation, episode_seconds, reward, start)
        self.num_envs = self._core.sim.n
        self.render_mode, self.render_view = render_mode, render_view
        self.single_observation_space = self._core.obs_space
        self.single_action_space = spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._rngs = [np.random.default_rng() for _ in range(self.num_envs)]
        self._needs_reset = np.zeros(self.num_envs, dtype=bool)

    @property
    def sim(self) -> Simulator:
        return self._core.sim

    def _reset_one(self, i: int, seed: int | None) -> None:
        if seed is not None:
            self._rngs[i] = np.random.default_rng(seed)
        episode = seed if seed is not None else int(self._rngs[i].integers(2**63))
        self.sim.reset(i, episode)

    def reset(self, *, seed: int | list[int] | None = None, options: dict | None = None):
        if isinstance(seed, int):
            seeds: list[int | None] = [seed + i for i in range(self.num_envs)]
        elif seed is None:
            seeds = [None] * self.num_envs
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"{len(seeds)} seeds for {self.num_envs} envs")
        for i, s in enumerate(seeds):
            self._reset_one(i, s)
        self._needs_reset[:] = False
        self._core.__dict__.pop("terms", None)
        return self._core.observe(), self._infos()

    def step(self, actions):
        actions = np.asarray(actions, dtype=np.float64).reshape(self.num_envs, 2)
        reset_now = self._needs_reset.copy()
        reward, term, trunc = self._core.step(actions)
        for i in np.flatnonzero(reset_now):
            self._reset_one(int(i), None)
        reward[reset_now] = 0.0
        term[reset_now] = False
        trunc[reset_now] = False
        for v in self._core.terms.values():
            v[reset_now] = 0.0
        self._needs_reset = term | trunc
        return self._core.observe(), reward, term, trunc, self._infos()

    def _infos(self) -> dict[str, Any]:
        s = self.sim.state
        info: dict[str, Any] = {
            "pose": s[:, :3].copy(),
            "velocity": s[:, 3:5].copy(),
            "lane_pose": self.sim.lane.copy(),
            "lane_pose_fields": LANE_POSE_FIELDS,
            "on_road": self.sim.lane[:, LP.ON_ROAD] > 0.5,
            "collision": self.sim.collided.copy(),
            "time": self.sim.time.copy(),
        }
        if hasattr(self._core, "terms"):
            info["reward_terms"] = {k: v.copy() for k, v in self._core.terms.items()}
        return info

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        if self.render_view == "top_down":
            return top_down(self.sim.map, self.sim.state[:, :3], params=self.sim.params[0])
        self.sim.enable_rendering()
        frames = self.sim.render()
        if self.render_view == "camera":
            return frames
        return np.stack([view_frame(self.sim, i, "both", frames[i]) for i in range(self.num_envs)])
