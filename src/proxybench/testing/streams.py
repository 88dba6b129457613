"""The observations an agent contract feeds its agent: recorded once from the simulator, replayed as often as needed.

An agent is checked in isolation: its commands do not move the robot, so every play of an episode sees
exactly the same observations (the only way to tell *reset determinism* and *state shared between
episodes* apart from a world that changed). A stream is recorded by the runner's episode engine
(:func:`~proxybench.runner.episode.sim_plant`: the JPEG round trip camera agents see) while the expert
drives, and keeps everything a robot can report: the frame, odometry, the front range, and the ground truth
(true lane pose, route, pose) that only privileged agents are given.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field

from proxybench.agents.base import Observation
from proxybench.agents.zoo import make_agent
from proxybench.domain.params import DomainParams
from proxybench.protocol import jpeg
from proxybench.runner.episode import SimPlant, sim_plant
from proxybench.runner.rollout import AgentPolicy, rollout

__all__ = ["LANE_POSE_SHIFT", "Frame", "StreamSpec", "as_seen", "record_stream"]

#: how far the "shifted" ground truth is from the true one: lateral [m], heading error [rad]
LANE_POSE_SHIFT = (0.05, 0.1)


def _small() -> DomainParams:
    return DomainParams(image_width=160, image_height=120)


@dataclass(frozen=True)
class StreamSpec:
    """The episodes an agent is fed: ``map``, θ (``params``: image size, frame rate), ``seconds`` each, one per
    seed of ``seeds`` (at least two: episode 2 must differ from episode 1), driven by ``driver`` (a zoo agent
    that stays on the road, so the ground truth stays valid)."""

    map: str = "loop_3x3"
    params: DomainParams = field(default_factory=_small)
    seconds: float = 1.0
    seeds: tuple[int, ...] = (1, 2)
    driver: str = "pure-pursuit"

    def __post_init__(self) -> None:
        if len(self.seeds) < 2 or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"StreamSpec: seeds must be at least two different seeds, got {self.seeds}")
        if not self.seconds > 0:
            raise ValueError(f"StreamSpec: seconds must be positive, got {self.seconds}")

    @property
    def frame_rate(self) -> float:
        return self.params.frame_rate

    def stream(self, episode: int) -> tuple[Frame, ...]:
        """Episode ``episode`` (an index into ``seeds``): every frame's full observation, ground truth included."""
        return record_stream(self.map, self.params.model_dump_json(), self.seeds[episode], self.seconds, self.driver)


@dataclass(frozen=True)
class Frame:
    """One recorded frame: the full observation (frame, odometry, ground truth) and the camera frame's JPEG."""

    obs: Observation
    jpg: bytes | None


@functools.lru_cache(maxsize=32)
def record_stream(map_name: str, params_json: str, seed: int, seconds: float, driver: str) -> tuple[Frame, ...]:
    """One episode's frames as the runner makes them (the JPEG round trip camera agents see), with the true lane
    pose and route of every frame; cached per process (streams are small and reused)."""
    plant = _plant(map_name, params_json)
    seen: list[Frame] = []

    def keep(k: int, images, alive, p: SimPlant) -> None:
        image = None if images is None else images[0]
        obs = p.observation(0, image, True)
        ahead = obs.front_range  # read now: the reader would read the simulator as it is when the frame is replayed
        obs = dataclasses.replace(obs, range_reader=lambda: ahead)
        seen.append(Frame(obs, None if image is None else jpeg.jpeg_of(image)))

    rollout(plant, AgentPolicy([make_agent(driver)]), [seed], seconds, camera=True, on_frame=keep)
    return tuple(seen)


@functools.lru_cache(maxsize=4)
def _plant(map_name: str, params_json: str) -> SimPlant:
    """One simulator plant per map and θ, reused for every seed (building one costs more than its episodes)."""
    return sim_plant(map_name, DomainParams.model_validate_json(params_json))


def as_seen(frame: Frame, privileged: bool, lane_pose: str = "as-run") -> Observation:
    """A frame's observation as an agent is given it: ``as-run`` is what the runner gives (privileged agents:
    ground truth and no camera frame; camera agents: the frame and no ground truth); ``given`` adds the ground
    truth to a camera agent's; ``shifted`` gives a privileged agent a lane pose moved by :data:`LANE_POSE_SHIFT`.

    The true pose (``pose``) is ground truth too: camera agents are not given it, and ``shifted`` moves it with
    the lane pose (sideways by the lateral shift, turned by the heading shift). A camera frame is decoded afresh
    from its JPEG each time (:func:`~proxybench.protocol.jpeg.decode_received`), so that a node agent is sent the
    very same bytes on every play, not a re-encoding of decoded pixels.
    """
    obs = frame.obs
    if not privileged:
        camera = obs.camera if frame.jpg is None else jpeg.decode_received(frame.jpg)
        if lane_pose == "given":
            return dataclasses.replace(obs, camera=camera)
        return dataclasses.replace(obs, camera=camera, lane_pose=None, route=None, pose=None)
    out = dataclasses.replace(obs, camera=None)
    if lane_pose == "shifted" and obs.lane_pose is not None:
        lateral, heading = LANE_POSE_SHIFT
        lp = obs.lane_pose
        out = dataclasses.replace(out, lane_pose=dataclasses.replace(lp, lateral=lp.lateral + lateral,
                                                                     heading_error=lp.heading_error + heading))
        if obs.pose is not None:
            x, y, th = obs.pose
            out = dataclasses.replace(out, pose=(x - lateral * math.sin(th), y + lateral * math.cos(th), th + heading))
    return out
