"""The caller side of the robot protocol: drive a robot node (simulator or physical robot's bridge).

:class:`RobotProcess` is :class:`~.process.NodeProcess` (timeouts on every wait, process group killed and
reaped, every misbehaviour one :class:`~.failures.RobotFailure` with a stable reason) speaking the robot
language, with typed requests and answers; setup and per-frame exchanges are pipelined into one write each.
:class:`RemoteRobot` is what the runner holds: one robot, episodes on demand, a fresh process after a
failure.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from proxybench.domain.maps import Map
from proxybench.protocol import robot_wire as rw
from proxybench.protocol import wire
from proxybench.protocol.failures import ROBOT_REASONS, RobotFailure
from proxybench.protocol.language import ROBOT_OUTPUTS, ROBOT_REPLIES, RobotLanguage
from proxybench.protocol.process import NodeProcess
from proxybench.protocol.session import NodeSession

__all__ = ["ROBOT_REASONS", "RemoteRobot", "RobotProcess", "map_yaml"]

T = TypeVar("T")


def map_yaml(m: Map) -> str:
    """The YAML text ``set_map`` sends for ``m`` (its source file)."""
    path = Path(m.path)
    if not path.is_file():
        raise ValueError(f"map {m.name!r} has no source file ({m.path!r}) to send to a robot node")
    return path.read_text(encoding="utf-8")


class RobotProcess(NodeProcess):
    """A robot node in a child process, started and handshaken on construction.

    Options as :class:`~.process.NodeProcess`: ``init_timeout`` bounds start + handshake and each setup
    request (seed, clear, set_map, spawn_robot, get_robot_interface_description, episode_start, meta);
    ``step_timeout`` each per-frame request (set_robot_commands, step, get_robot_observations,
    get_robot_state, get_sim_state, get_robot_performance). A robot node that steps in real time needs a
    ``step_timeout`` longer than one step.
    """

    language_class = RobotLanguage
    data_replies = ROBOT_REPLIES
    node_outputs = ROBOT_OUTPUTS
    required_inputs = ("clear", "episode_start", "get_robot_observations", "get_robot_state", "get_sim_state",
                       "set_map", "set_robot_commands", "spawn_robot", "step")
    required_outputs = ("robot_observations", "robot_state", "sim_state")
    failure_class = RobotFailure
    _SETUP = frozenset({"seed", "clear", "set_map", "spawn_robot", "get_robot_interface_description",
                        "episode_start"})

    # ---------------------------------------------------------------------------------- setup requests
    def seed(self, seed: int) -> None:
        self._exchange([("seed", wire.encode_seed(seed))])

    def setup_episode(self, map_text: str, robot_name: str, episode_name: str, payload: dict[str, Any], *,
                      pose: tuple[float, float, float], simulate_camera: bool = True,
                      default_frame_rate: float = 15.0) -> rw.RobotInfo:
        """clear, set_map, spawn_robot (at ``pose``), get_robot_interface_description and episode_start in
        one write; what the robot says it is (a robot that does not say is stepped at
        ``default_frame_rate``). ``payload`` becomes ``episode_start.yaml_payload`` (as JSON)."""
        replies = self._exchange([
            ("clear", rw.encode_clear()), ("set_map", rw.encode_set_map(map_text)),
            ("spawn_robot", rw.encode_spawn_robot(robot_name, pose, simulate_camera=simulate_camera)),
            ("get_robot_interface_description", rw.encode_get_robot_interface_description(robot_name)),
            ("episode_start", wire.encode_episode_start(episode_name, json.dumps(payload))),
        ])
        return self._parse(lambda d: rw.parse_robot_info(d, default_frame_rate), replies[3][0], None)

    # ------------------------------------------------------------------------------ per-frame requests
    def set_commands(self, robot_name: str, t_effective: float, wheels: np.ndarray) -> None:
        self._exchange([("set_robot_commands", rw.encode_set_robot_commands(robot_name, t_effective, *wheels))])

    def step(self, until: float) -> None:
        self._exchange([("step", rw.encode_step(until))])

    def get_observations(self, robot_name: str, t_effective: float) -> rw.RobotObservationsData:
        (reply,) = self._exchange([("get_robot_observations",
                                    rw.encode_get_robot_observations(robot_name, t_effective))])
        return self._parse(rw.parse_robot_observations, reply[0], robot_name)

    def get_state(self, robot_name: str, t_effective: float) -> rw.RobotStateData:
        (reply,) = self._exchange([("get_robot_state", rw.encode_get_robot_state(robot_name, t_effective))])
        return self._parse(rw.parse_robot_state, reply[0], robot_name)

    def get_sim_state(self) -> rw.SimState:
        (reply,) = self._exchange([("get_sim_state", rw.encode_get_sim_state())])
        return self._parse(rw.parse_sim_state, reply[0], None)

    def get_performance(self, robot_name: str) -> dict[str, float]:
        """Cumulative metric values by name (``robot_performance.performance.metrics.*.cumulative_value``)."""
        (reply,) = self._exchange([("get_robot_performance", rw.encode_get_robot_performance(robot_name))])
        return self._parse(_performance, reply[0], robot_name)

    def frame(self, robot_name: str, t_effective: float, wheels: np.ndarray, until: float, *,
              observe: bool = True) -> tuple[rw.SimState, rw.RobotStateData, rw.RobotObservationsData | None]:
        """One control period in one write: set_robot_commands(``wheels`` at ``t_effective``), step(``until``),
        get_sim_state, get_robot_state and, with ``observe``, get_robot_observations at ``until``."""
        items = [("set_robot_commands", rw.encode_set_robot_commands(robot_name, t_effective, *wheels)),
                 ("step", rw.encode_step(until)), ("get_sim_state", rw.encode_get_sim_state()),
                 ("get_robot_state", rw.encode_get_robot_state(robot_name, until))]
        if observe:
            items.append(("get_robot_observations", rw.encode_get_robot_observations(robot_name, until)))
        replies = self._exchange(items)
        sim = self._parse(rw.parse_sim_state, replies[2][0], None)
        state = self._parse(rw.parse_robot_state, replies[3][0], robot_name)
        obs = self._parse(rw.parse_robot_observations, replies[4][0], robot_name) if observe else None
        return sim, state, obs

    # -------------------------------------------------------------------------------------- plumbing
    def _exchange(self, items: list[tuple[str, bytes]]) -> list[list[wire.Topic]]:
        """Write every request at once (checked against the language first), then collect every answer."""
        self._usable()
        topics = [topic for topic, _ in items]
        self._check_order(*topics)
        setup = any(t in self._SETUP for t in topics)
        timeout, reason = (self.init_timeout, "init-timeout") if setup else (self.step_timeout, "step-timeout")
        plans = [self._data_plan(t) for t in topics]
        return self._request(b"".join(p for _, p in items), plans, time.monotonic() + timeout, reason)

    def _parse(self, parse: Callable[[Any], T], reply: wire.Topic, robot_name: str | None) -> T:
        try:
            out = parse(reply.data)
        except wire.MessageTypeError as exc:
            self._fail("bad-data", str(exc))
            raise  # unreachable: _fail raises
        name = getattr(out, "robot_name", None)
        if robot_name is not None and name is not None and name != robot_name:
            self._fail("bad-data", f"{reply.topic} is about robot {name!r}, asked about {robot_name!r}")
        return out


def _performance(data: Any) -> dict[str, float]:
    perf = data.get("performance") if isinstance(data, dict) else None
    metrics = perf.get("metrics") if isinstance(perf, dict) else None
    if not isinstance(metrics, dict):
        raise wire.MessageTypeError("robot_performance: missing field 'performance.metrics' (a map)")
    out = {}
    for k, m in metrics.items():
        value = m.get("cumulative_value") if isinstance(m, dict) else None
        if type(value) not in (int, float):
            raise wire.MessageTypeError(f"robot_performance.performance.metrics[{k!r}].cumulative_value must be a "
                                        f"number")
        out[str(k)] = float(value)
    return out


class RemoteRobot(NodeSession):
    """A robot node process driving one robot named ``robot_name``, as the runner uses it.

    :meth:`start_episode` sends ``seed`` on the first episode of each process, then the episode setup:
    ``spawn_robot`` at the start pose (given, or drawn from the seed as the simulator draws it: AIDO's
    simulators are told where the robot stands), and ``episode_start`` whose ``yaml_payload`` carries the
    per-episode seed, the exact start pose and the episode length with ``proxybench: true`` (ask for the
    extensions: exact state, tick trace, true lane pose; robots that do not know them ignore the keys).
    A robot that does not say its frame rate is stepped at ``frame_rate`` [Hz]. With ``restart=True`` the
    episode after a failure starts a fresh process (counted in ``restarts``). Other keyword arguments go
    to :class:`RobotProcess`.
    """

    def __init__(self, cmd: str | Sequence[str], *, robot_name: str = "ego", restart: bool = True,
                 frame_rate: float = 15.0, **process_kwargs: Any):
        self._cmd = cmd
        self._kwargs = process_kwargs
        self.robot_name = robot_name
        self.frame_rate = float(frame_rate)
        self._nets: dict[str, Any] = {}  # map path → its LaneNetwork, to draw starts
        self._init_session(lambda: RobotProcess(self._cmd, **self._kwargs), restart)

    @property
    def command(self) -> str:
        return self._cmd if isinstance(self._cmd, str) else " ".join(map(str, self._cmd))

    def start_episode(self, map_: Map, seed: int, *, pose: tuple[float, float, float] | None = None,
                      seconds: float | None = None, episode: str | None = None, camera: bool = True,
                      route: Sequence[str] | None = None) -> rw.RobotInfo:
        """Set up and start one episode on ``map_`` from ``seed`` (and ``pose``, else drawn from the seed)."""
        name = self._begin_episode(seed, episode)
        if pose is None:  # imported here: an agent node importing proxybench.protocol needs no simulator
            from proxybench.domain.lanes import LaneNetwork
            from proxybench.domain.simulator import start_pose

            net = self._nets.get(map_.path)
            if net is None:
                net = self._nets[map_.path] = LaneNetwork(map_)
            pose = start_pose(map_, int(seed), net=net)
        payload: dict[str, Any] = {"seed": int(seed), "proxybench": True, "pose": [float(v) for v in pose]}
        if seconds is not None:
            payload["episode_seconds"] = float(seconds)
        if route is not None:
            payload["route"] = [str(t) for t in route]
        return self.process.setup_episode(map_yaml(map_), self.robot_name, name, payload, pose=pose,
                                          simulate_camera=camera, default_frame_rate=self.frame_rate)

    def observations(self, t: float) -> rw.RobotObservationsData:
        return self.process.get_observations(self.robot_name, t)

    def state(self, t: float) -> rw.RobotStateData:
        return self.process.get_state(self.robot_name, t)

    def frame(self, t: float, wheels: np.ndarray, until: float, *, observe: bool = True
              ) -> tuple[rw.SimState, rw.RobotStateData, rw.RobotObservationsData | None]:
        return self.process.frame(self.robot_name, t, wheels, until, observe=observe)

