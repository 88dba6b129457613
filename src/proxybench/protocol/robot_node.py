"""A robot node: one robot behind AIDO's simulator protocol, whatever world it lives in.

:class:`RobotNode` answers AIDO's ``protocol_simulator`` for the DB20 (``seed``; per episode ``clear``,
``set_map``, ``spawn_robot`` / ``spawn_duckie``, ``get_robot_interface_description``, ``episode_start``;
then ``set_robot_commands``, ``step``, ``get_robot_observations``, ``get_robot_state``, ``get_duckie_state``,
``get_sim_state``, ``get_robot_performance``, ``dump_state``, ``get_ui_image``), with the envelope, meta
topics and error answers of :class:`~.node.NodeLogic`, which the agent node uses too, so that AIDO's
experiment manager can drive it. The world is a *backend* (:class:`~.robot_backend.RobotBackend`):
proxybench's simulator (:mod:`proxybench.runner.sim_robot`, ``proxybench robot serve``), gym-duckietown
(:mod:`proxybench.gym.backend`, ``proxybench gym serve``), or a physical robot's bridge. One robot is
playable; non-playable robots and duckies stand still where they were spawned, as map objects the backend
places (seen by the camera, collided with). It is the reference implementation of docs/robot-protocol.md.

Time advances in whole camera frames (the backend's ``frame_dt``): ``step(until)`` runs every frame that
ends at or before ``until``; the wheel commands set last are held through them (the backend's own command
delay applies). Observations are taken when asked, for the current time.
"""

from __future__ import annotations

import json
import math
import time
from importlib.metadata import EntryPoint
from typing import Any, BinaryIO

import numpy as np
import yaml

from proxybench.domain.dynamics import wheel_ticks
from proxybench.domain.maps import Map, MapObject
from proxybench.domain.params import DomainParams
from proxybench.protocol import jpeg, robot_wire, wire
from proxybench.protocol.aido_arrays import robot_info_data
from proxybench.protocol.description import _commands, _observations, encode_extras
from proxybench.protocol.language import RobotLanguage
from proxybench.protocol.node import NodeLogic, serve_node
from proxybench.protocol.robot_backend import RobotBackend
from proxybench.protocol.robot_description import robot_protocol_description
from proxybench.untrusted import UntrustedInputError, load_yaml

__all__ = ["RobotBackend", "RobotNode", "serve_robot"]

_TURNS = ("left", "straight", "right")
#: the backend of a node given θ instead of a backend: proxybench's simulator, built in the runner (the one place
#: simulators are built), named by entry point as agents/kinds.py names checkpoints, not imported from above
SIMULATOR_BACKEND = EntryPoint("simulation", "proxybench.runner.sim_robot:SimRobot", "proxybench.robot_backends")
_UI_PX_PER_TILE = 48  # top-down image of get_ui_image


def _plain(value: Any) -> Any:
    """``value`` with NumPy scalars made Python numbers, so that it encodes as CBOR."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    if isinstance(value, np.integer | np.bool_):
        return value.item()
    if isinstance(value, np.floating):
        return float(value)
    return value


def _episode_payload(payload: str) -> dict[str, Any]:
    """The proxybench keys of ``episode_start.yaml_payload`` (JSON or YAML; other keys are ignored)."""
    try:
        doc = json.loads(payload)
    except ValueError:
        try:
            doc = load_yaml(payload, max_depth=16)
        except (yaml.YAMLError, UntrustedInputError) as exc:
            raise wire.MessageTypeError(f"episode_start: yaml_payload is neither JSON nor YAML: {exc}") from exc
    doc = doc if isinstance(doc, dict) else {}
    out: dict[str, Any] = {}
    if doc.get("seed") is not None:
        if type(doc["seed"]) is not int:
            raise wire.MessageTypeError(f"episode_start: yaml_payload.seed must be an integer, got {doc['seed']!r}")
        out["seed"] = doc["seed"]
    if doc.get("pose") is not None:
        pose = doc["pose"]
        if not (isinstance(pose, list) and len(pose) == 3 and all(type(v) in (int, float) for v in pose)
                and all(math.isfinite(v) for v in pose)):
            raise wire.MessageTypeError(f"episode_start: yaml_payload.pose must be [x, y, theta] "
                                        f"(finite numbers, m and rad), got {pose!r}")
        out["pose"] = tuple(float(v) for v in pose)
    if doc.get("episode_seconds") is not None:
        secs = doc["episode_seconds"]
        if type(secs) not in (int, float) or not (math.isfinite(secs) and secs > 0):
            raise wire.MessageTypeError(f"episode_start: yaml_payload.episode_seconds must be a positive number, "
                                        f"got {secs!r}")
        out["episode_seconds"] = float(secs)
    if doc.get("route") is not None:
        route = doc["route"]
        if not (isinstance(route, list) and all(t in _TURNS for t in route)):
            raise wire.MessageTypeError(f"episode_start: yaml_payload.route must be a list of turns {_TURNS}, "
                                        f"got {route!r}")
        out["route"] = route
    ext = doc.get("proxybench", False)
    if type(ext) is not bool:
        raise wire.MessageTypeError(f"episode_start: yaml_payload.proxybench must be true or false, got {ext!r}")
    out["proxybench"] = ext
    return out


class RobotNode(NodeLogic):
    """One robot behind the robot protocol, free of I/O (see :func:`serve_robot`); its world is ``backend``.

    ``seed``: the episode seed used when neither the ``seed`` topic nor ``episode_start.yaml_payload``
    gives one. Given a :class:`DomainParams` (or None) and ``map_`` instead of a backend, the node serves
    proxybench's simulator with that θ (:class:`proxybench.runner.sim_robot.SimRobot`), as it always has.
    """

    def __init__(self, backend: RobotBackend | DomainParams | None = None, map_: Map | str | None = None,
                 seed: int = 0, node_name: str = "robot", quality: int = jpeg.DEFAULT_QUALITY):
        if backend is None or isinstance(backend, DomainParams):
            backend = SIMULATOR_BACKEND.load()(backend, map_)
        elif map_ is not None:
            raise TypeError("RobotNode: give the map to the backend, not to the node")
        self.backend = backend
        self.seed = seed
        self.quality = quality
        self.robot: robot_wire.SpawnRobotData | None = None
        self.episode_name: str | None = None
        self.parked: dict[str, tuple[float, float, float]] = {}  # non-playable robots: name → pose
        self.duckies: dict[str, tuple[float, float, float]] = {}
        super().__init__(node_name, RobotLanguage(), robot_protocol_description(), {
            "seed": self._on_seed, "clear": self._on_clear, "set_map": self._on_set_map,
            "spawn_robot": self._on_spawn_robot, "spawn_duckie": self._on_spawn_duckie,
            "get_robot_interface_description": self._on_describe, "episode_start": self._on_episode_start,
            "step": self._on_step, "set_robot_commands": self._on_set_robot_commands,
            "get_robot_observations": self._on_observations, "get_robot_state": self._on_robot_state,
            "get_duckie_state": self._on_duckie_state, "get_sim_state": self._on_sim_state,
            "get_robot_performance": self._on_performance, "dump_state": self._on_dump_state,
            "get_ui_image": self._on_ui_image,
        })

    def __getattr__(self, name: str) -> Any:
        """The backend's own attributes read through the node (``node.sim`` of a simulator backend)."""
        backend = self.__dict__.get("backend")
        if backend is None or name.startswith("__"):
            raise AttributeError(name)
        return getattr(backend, name)

    # ---------------------------------------------------------------------------------------- helpers
    def _robot_named(self, name: str, topic: str) -> None:
        spawned = None if self.robot is None else self.robot.robot_name
        if name != spawned:
            raise ValueError(f"{topic}: unknown robot {name!r}; spawned: {[spawned] if spawned else []}")

    def _timing(self, start: int) -> dict:
        return wire.node_timing(self.name, start)

    @property
    def _time(self) -> float:
        return self.backend.time()

    # ---------------------------------------------------------------------------------- setup topics
    def _on_clear(self, data: Any) -> list[bytes]:
        if data is not None:
            raise wire.MessageTypeError(f"clear: data must be null, got {type(data).__name__}")
        self._advance("clear")
        self.robot, self.episode_name = None, None
        self.parked, self.duckies = {}, {}
        return []

    def _on_set_map(self, data: Any) -> list[bytes]:
        text = robot_wire.parse_set_map(data)
        self._advance("set_map")
        self.backend.set_map(text)
        return []

    def _taken(self, name: str, topic: str) -> None:
        if name in self.parked or name in self.duckies or (self.robot is not None and self.robot.robot_name == name):
            raise ValueError(f"{topic}: the name {name!r} is already spawned in this episode")

    def _on_spawn_robot(self, data: Any) -> list[bytes]:
        spawn = robot_wire.parse_spawn_robot(data)
        self._advance("spawn_robot")
        self._taken(spawn.robot_name, "spawn_robot")
        if not spawn.playable:
            if spawn.pose is None:
                raise ValueError(f"spawn_robot: the non-playable robot {spawn.robot_name!r} needs a configuration")
            self.parked[spawn.robot_name] = spawn.pose  # stands still: AIDO's simulator parks NPC robots too
            return []
        if self.robot is not None:
            raise ValueError(f"spawn_robot: this node simulates one playable robot and {self.robot.robot_name!r} is "
                             f"already spawned; cannot add {spawn.robot_name!r}")
        self.robot = spawn
        return []

    def _on_spawn_duckie(self, data: Any) -> list[bytes]:
        duckie = robot_wire.parse_spawn_duckie(data)
        self._advance("spawn_duckie")
        self._taken(duckie.name, "spawn_duckie")
        self.duckies[duckie.name] = duckie.pose
        return []

    def _extra_objects(self) -> tuple[MapObject, ...]:
        return tuple([MapObject("duckiebot", x, y, th, name=k) for k, (x, y, th) in self.parked.items()]
                     + [MapObject("duckie", x, y, th, name=k) for k, (x, y, th) in self.duckies.items()])

    def _on_describe(self, data: Any) -> list[bytes]:
        name = robot_wire.parse_robot_name(data, "get_robot_interface_description")
        self._advance("get_robot_interface_description")
        start = time.time_ns()
        self._robot_named(name, "get_robot_interface_description")
        return [robot_wire.encode_robot_interface_description(name, _observations(False), _commands(),
                                                              self.backend.info(), self._timing(start))]

    def _on_episode_start(self, data: Any) -> list[bytes]:
        name, payload = wire.parse_episode_start(data)
        options = _episode_payload(payload)
        if self.robot is None:
            raise ValueError("episode_start: no robot spawned (send spawn_robot after set_map)")
        self._advance("episode_start")
        seed = options.get("seed", self.seed)
        self.backend.reset(int(seed), options.get("pose", self.robot.pose), options.get("route"),
                           self._extra_objects(), camera=self.robot.simulate_camera)
        self.episode_name = name
        self.extensions = options["proxybench"]
        secs = options.get("episode_seconds")
        self.frame_limit = None if secs is None else max(1, round(secs / self.backend.frame_dt))
        self.frames = 0
        self.commands = np.zeros(2)
        self.leds = wire.DEFAULT_LEDS
        self.termination: dict | None = None
        self.distance = 0.0
        self._frame: tuple[int, bytes] | None = None
        self._rows: list[np.ndarray] = [self._start_row()] if self.extensions else []
        self._lanes: list[tuple[int, int]] = []  # per frame stepped: the route's pinned and next lane before it
        return []

    def _start_row(self) -> np.ndarray:
        s = self.backend.state()
        return np.array([[0.0, *s.pose, s.v, s.omega, 0.0, 0.0]])

    # -------------------------------------------------------------------------------- episode topics
    def _on_set_robot_commands(self, data: Any) -> list[bytes]:
        name, _t, wheels = robot_wire.parse_set_robot_commands(data)
        self._advance("set_robot_commands")
        self._robot_named(name, "set_robot_commands")
        self.commands = np.zeros(2) if self.termination is not None else wheels  # AIDO: a finished robot stops
        leds = data["commands"].get("LEDS")
        self.leds = leds if isinstance(leds, dict) else wire.DEFAULT_LEDS
        return []

    def _on_step(self, data: Any) -> list[bytes]:
        until = robot_wire.parse_step(data)
        self._advance("step")
        backend = self.backend
        now = self._time
        if until < now - 1e-9:
            raise ValueError(f"step: until = {until!r} s is before the current time {now!r} s; time cannot go back")
        target = math.floor(until / backend.frame_dt + 1e-6)
        for _ in range(max(0, target - self.frames)):
            x0, y0 = backend.state().pose[:2]
            done = backend.step_frame(self.commands if self.termination is None else np.zeros(2))
            self.frames += 1
            for x, y in done.trace[:, 1:3].tolist():
                self.distance += math.hypot(x - x0, y - y0)
                x0, y0 = x, y
            if self.extensions:
                self._lanes.append(done.lanes)
                self._rows.append(done.trace)
            self._check_termination()
        return []

    def _check_termination(self) -> None:
        if self.termination is not None:
            return
        when = self._time
        end = self.backend.ending()
        if end is not None:  # the backend's rule (the runner's, for proxybench's simulator)
            self.termination = {"when": end.t, "desc": end.message, "code": str(end.kind)}
            if end.with_ is not None:
                self.termination["with"] = end.with_
        elif self.frame_limit is not None and self.frames >= self.frame_limit:
            self.termination = {"when": when, "desc": "the episode's time is up", "code": "timeout"}

    def _on_observations(self, data: Any) -> list[bytes]:
        name, _t = robot_wire.parse_named_request(data, "get_robot_observations")
        self._advance("get_robot_observations")
        start = time.time_ns()
        self._robot_named(name, "get_robot_observations")
        backend = self.backend
        jpg = b""
        if self.robot.simulate_camera:
            if self._frame is None or self._frame[0] != self.frames:
                self._frame = (self.frames, jpeg.encode(backend.camera(), self.quality))
            jpg = self._frame[1]
        res = backend.encoder_resolution
        ticks = wheel_ticks(backend.state().wheels, res)
        extras = self._lane_extras() if self.extensions else None
        obs = wire.observations_data(jpg, self._time, (float(ticks[0] * res), float(ticks[1] * res)), res, extras)
        return [robot_wire.encode_robot_observations(name, self._time, obs, self._timing(start))]

    def _lane_extras(self) -> dict[str, Any]:
        """``observations.proxybench``: the true lane pose and, where the backend has routes, the route."""
        lane = self.backend.lane()
        if lane is None:
            return encode_extras(None)
        pose, route = lane
        extras = encode_extras(pose)
        if route is not None:
            extras["route"] = {"next_turn": route.next_turn, "stop_distance": float(route.stop_distance),
                               "in_intersection": bool(route.in_intersection)}
        return extras

    def _on_robot_state(self, data: Any) -> list[bytes]:
        name, _t = robot_wire.parse_named_request(data, "get_robot_state")
        self._advance("get_robot_state")
        start = time.time_ns()
        if name in self.parked:
            return [robot_wire.encode_robot_state(name, self._time, self.parked[name], 0.0, 0.0, np.zeros(2),
                                                  wire.DEFAULT_LEDS, None, self._timing(start))]
        self._robot_named(name, "get_robot_state")
        s = self.backend.state()
        extras = None
        if self.extensions:
            rows = np.vstack(self._rows) if self._rows else np.zeros((0, len(robot_wire.TRACE_COLUMNS)))
            self._rows = []
            extras = {"pose": list(s.pose), "v": s.v, "omega": s.omega, "off_road": s.off_road,
                      "collided": s.collided,
                      "trace": {k: rows[:, i].tolist() for i, k in enumerate(robot_wire.TRACE_COLUMNS)}}
            routes = self.backend.route_choices()
            if routes is not None:
                extras["route"] = {"active": routes["active"], "choices": _plain(routes["choices"]),
                                   "pins": [p for p, _ in self._lanes], "nexts": [n for _, n in self._lanes]}
            self._lanes = []
        return [robot_wire.encode_robot_state(name, self._time, s.pose, s.v, s.omega, self.commands,
                                              self.leds, extras, self._timing(start))]

    def _on_sim_state(self, data: Any) -> list[bytes]:
        if data is not None:
            raise wire.MessageTypeError(f"get_sim_state: data must be null, got {type(data).__name__}")
        self._advance("get_sim_state")
        start = time.time_ns()
        terms = {self.robot.robot_name: self.termination, **dict.fromkeys(self.parked)}
        return [robot_wire.encode_sim_state(self.termination is not None, terms, self._timing(start))]

    def _on_duckie_state(self, data: Any) -> list[bytes]:
        name, _t = robot_wire.parse_named_request(data, "get_duckie_state", "duckie_name")
        self._advance("get_duckie_state")
        start = time.time_ns()
        if name not in self.duckies:
            raise ValueError(f"get_duckie_state: unknown duckie {name!r}; spawned: {sorted(self.duckies)}")
        return [robot_wire.encode_duckie_state(name, self._time, self.duckies[name], self._timing(start))]

    def _on_dump_state(self, data: Any) -> list[bytes]:
        robot_wire.parse_dump_state(data)
        self._advance("dump_state")
        start = time.time_ns()
        s = self.backend.state()
        bots = {self.robot.robot_name: robot_info_data(s.pose, s.v, s.omega, self.commands, self.leds)}
        for name, pose in self.parked.items():
            bots[name] = robot_info_data(pose, 0.0, 0.0, (0.0, 0.0), wire.DEFAULT_LEDS)
        return [robot_wire.encode_state_dump(self._time, bots, self.duckies, self._timing(start))]

    def _on_ui_image(self, data: Any) -> list[bytes]:
        if data is not None:
            raise wire.MessageTypeError(f"get_ui_image: data must be null, got {type(data).__name__}")
        self._advance("get_ui_image")
        start = time.time_ns()
        img = self.backend.top_view(_UI_PX_PER_TILE)
        return [robot_wire.encode_ui_image(jpeg.encode(img, self.quality), self._timing(start))]

    def _on_performance(self, data: Any) -> list[bytes]:
        name = robot_wire.parse_robot_name(data, "get_robot_performance")
        self._advance("get_robot_performance")
        start = time.time_ns()
        self._robot_named(name, "get_robot_performance")
        survived = self.termination["when"] if self.termination is not None else self._time
        metrics = {"survival_time": (True, survived, "Simulated time until the episode ended [s]."),
                   "distance_driven": (True, self.distance, "Path length of the robot centre [m].")}
        return [robot_wire.encode_robot_performance(name, self._time, metrics, self._timing(start))]

    def _node_description(self) -> str:
        return self.backend.description()


def serve_robot(node: RobotNode, data_in: str | int | BinaryIO | None = None,
                data_out: str | int | BinaryIO | None = None, *, exit_on_abort: bool = True) -> int:
    """Serve ``node`` on ``$AIDONODE_DATA_IN`` / ``$AIDONODE_DATA_OUT`` (else stdin/stdout) until EOF."""
    return serve_node(node, data_in, data_out, exit_on_abort=exit_on_abort)
