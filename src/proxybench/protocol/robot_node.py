"""The proxybench simulator as a robot node: one *simulated* Duckiebot behind AIDO's simulator protocol.

:class:`RobotNode` wraps a :class:`~proxybench.domain.simulator.Simulator` of one robot and answers AIDO's
``protocol_simulator`` for the DB20 (``seed``; per episode ``clear``, ``set_map``, ``spawn_robot`` /
``spawn_duckie``, ``get_robot_interface_description``, ``episode_start``; then ``set_robot_commands``,
``step``, ``get_robot_observations``, ``get_robot_state``, ``get_duckie_state``, ``get_sim_state``,
``get_robot_performance``, ``dump_state``, ``get_ui_image``), with the envelope, meta topics and error
answers of :class:`~.node.NodeLogic`, which the agent node uses too, so that AIDO's experiment manager can
drive it. One robot is playable; non-playable robots and duckies stand still where they were spawned, as
map objects (seen by the camera, collided with). It is the reference implementation of
docs/robot-protocol.md, and a test double for a physical robot's bridge: the runner cannot tell the two
apart, except that this one says ``kind: "simulation"``.

Time advances in whole camera frames (1/frame_rate s): ``step(until)`` runs every frame that ends at or
before ``until``; the wheel commands set last are held through them (the simulator's own command delay
applies). Observations are rendered when asked, for the current time.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np
import yaml

from proxybench.domain.dynamics import ST, TRACE_FIELDS, wheel_ticks
from proxybench.domain.episode_end import end_event, ended
from proxybench.domain.lane_pose import LanePose
from proxybench.domain.maps import Map, MapError, MapObject, load_map, parse_map
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator
from proxybench.domain.topdown import top_down
from proxybench.protocol import jpeg, robot_wire, wire
from proxybench.protocol.aido_arrays import robot_info_data
from proxybench.protocol.description import _commands, _observations, encode_extras
from proxybench.protocol.language import RobotLanguage
from proxybench.protocol.node import NodeLogic, serve_node
from proxybench.protocol.robot_description import robot_protocol_description

__all__ = ["RobotNode", "serve_robot"]

_TURNS = ("left", "straight", "right")
_TRACE_IDX = [TRACE_FIELDS.index(k) for k in robot_wire.TRACE_COLUMNS[1:]]
_MAX_SIMS = 4
_UI_PX_PER_TILE = 48  # top-down image of get_ui_image


def _map_text(m: Map) -> str | None:
    path = Path(m.path)
    return path.read_text(encoding="utf-8") if path.is_file() else None


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
            doc = yaml.safe_load(payload)
        except yaml.YAMLError as exc:
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
    """One simulated robot behind the robot protocol, free of I/O (see :func:`serve_robot`).

    ``params``: θ of the robot (default :class:`DomainParams`); ``map_``: a map to build the simulator for
    up front (``set_map`` with its text then costs nothing; other maps are built when set); ``seed``: the
    episode seed used when neither the ``seed`` topic nor ``episode_start.yaml_payload`` gives one.
    """

    def __init__(self, params: DomainParams | None = None, map_: Map | str | None = None, seed: int = 0,
                 node_name: str = "robot", quality: int = jpeg.DEFAULT_QUALITY):
        self.params = params or DomainParams()
        self.default_seed = seed
        self.quality = quality
        self._sims: dict[tuple[str, tuple[MapObject, ...]], Simulator] = {}
        self.sim: Simulator | None = None
        self.robot: robot_wire.SpawnRobotData | None = None
        self.episode_name: str | None = None
        self._map_text: str | None = None
        self.parked: dict[str, tuple[float, float, float]] = {}  # non-playable robots: name → pose
        self.duckies: dict[str, tuple[float, float, float]] = {}
        if map_ is not None:
            m = load_map(map_) if isinstance(map_, str) else map_
            text = _map_text(m)
            if text is None:
                raise ValueError(f"map {m.name!r} has no source file, so set_map could never select it")
            self._sims[(text, ())] = self._build(m)
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
        self._trace = np.zeros((1, self.params.substeps, len(TRACE_FIELDS)))

    # ---------------------------------------------------------------------------------------- helpers
    def _build(self, m: Map) -> Simulator:
        """A simulator for ``m``, its compiled kernels loaded (or compiled) now, within the caller's init
        timeout, rather than at the first frame, within its step timeout; episode_start resets it."""
        sim = Simulator(m, self.params)
        sim.render()
        sim.step(np.zeros((1, 2)))
        return sim

    def _robot_named(self, name: str, topic: str) -> None:
        spawned = None if self.robot is None else self.robot.robot_name
        if name != spawned:
            raise ValueError(f"{topic}: unknown robot {name!r}; spawned: {[spawned] if spawned else []}")

    def _timing(self, start: int) -> dict:
        return wire.node_timing(self.name, start)

    @property
    def _time(self) -> float:
        return float(self.sim.time[0])

    # ---------------------------------------------------------------------------------- setup topics
    def _on_seed(self, data: Any) -> list[bytes]:
        seed = wire.parse_seed(data)
        self._advance("seed")
        self.default_seed = seed
        return []

    def _on_clear(self, data: Any) -> list[bytes]:
        if data is not None:
            raise wire.MessageTypeError(f"clear: data must be null, got {type(data).__name__}")
        self._advance("clear")
        self.robot, self.episode_name = None, None
        self.parked, self.duckies = {}, {}
        return []

    def _simulator(self, text: str, extra: tuple[MapObject, ...] = ()) -> Simulator:
        """The simulator of map ``text`` with ``extra`` objects (parked robots, duckies), built once."""
        key = (text, extra)
        if key not in self._sims:
            try:
                m = parse_map(text, path="<set_map.map_data>", name="set_map")
            except MapError as exc:
                raise ValueError(f"set_map: map_data is not a valid map:\n{exc}") from exc
            if extra:
                m = dataclasses.replace(m, objects=m.objects + extra)
            if len(self._sims) >= _MAX_SIMS:
                self._sims.pop(next(iter(self._sims)))
            self._sims[key] = self._build(m)
        return self._sims[key]

    def _on_set_map(self, data: Any) -> list[bytes]:
        text = robot_wire.parse_set_map(data)
        self._advance("set_map")
        self.sim = self._simulator(text)
        self._map_text = text
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

    def _info(self) -> dict[str, Any]:
        p = self.params
        return {"kind": "simulation", "frame_rate": float(p.frame_rate), "physics_rate": float(p.physics_rate),
                "wheel_distance": float(p.wheel_distance), "encoder_resolution": float(p.encoder_resolution),
                "image_width": p.image_width, "image_height": p.image_height, "params": p.model_dump(mode="json")}

    def _on_describe(self, data: Any) -> list[bytes]:
        name = robot_wire.parse_robot_name(data, "get_robot_interface_description")
        self._advance("get_robot_interface_description")
        start = time.time_ns()
        self._robot_named(name, "get_robot_interface_description")
        return [robot_wire.encode_robot_interface_description(name, _observations(False), _commands(), self._info(),
                                                              self._timing(start))]

    def _on_episode_start(self, data: Any) -> list[bytes]:
        name, payload = wire.parse_episode_start(data)
        options = _episode_payload(payload)
        if self.robot is None:
            raise ValueError("episode_start: no robot spawned (send spawn_robot after set_map)")
        self._advance("episode_start")
        extra = self._extra_objects()
        if extra:
            self.sim = self._simulator(self._map_text, extra)
        sim = self.sim
        seed = options.get("seed", self.default_seed)
        sim.reset(0, int(seed), options.get("pose", self.robot.pose), options.get("route"))
        self.episode_name = name
        self.extensions = options["proxybench"]
        secs = options.get("episode_seconds")
        self.frame_limit = None if secs is None else max(1, round(secs / sim.frame_dt))
        self.commands = np.zeros(2)
        self.leds = wire.DEFAULT_LEDS
        self.termination: dict | None = None
        self.distance = 0.0
        self._frame: tuple[int, bytes] | None = None
        self._rows: list[np.ndarray] = [self._start_row()] if self.extensions else []
        self._lanes: list[tuple[int, int]] = []  # per frame stepped: the route's pinned and next lane before it
        return []

    def _start_row(self) -> np.ndarray:
        s = self.sim.state[0]
        return np.array([[0.0, s[ST.X], s[ST.Y], s[ST.THETA], s[ST.V], s[ST.OMEGA], 0.0, 0.0]])

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
        sim = self.sim
        now = self._time
        if until < now - 1e-9:
            raise ValueError(f"step: until = {until!r} s is before the current time {now!r} s; time cannot go back")
        target = math.floor(until / sim.frame_dt + 1e-6)
        ticks = np.arange(1, sim.substeps + 1)
        for _ in range(max(0, target - int(sim.frame_index[0]))):
            first_tick = int(sim.frame_index[0]) * sim.substeps
            x0, y0 = float(sim.state[0, ST.X]), float(sim.state[0, ST.Y])
            if self.extensions:
                self._lanes.append((int(sim.routes.pin[0]), int(sim.routes.next[0])))
            sim.step(self.commands[None] if self.termination is None else np.zeros((1, 2)), self._trace)
            rows = self._trace[0]
            for x, y in rows[:, :2].tolist():
                self.distance += math.hypot(x - x0, y - y0)
                x0, y0 = x, y
            if self.extensions:
                block = np.empty((sim.substeps, len(robot_wire.TRACE_COLUMNS)))
                block[:, 0] = (ticks + first_tick) * sim.params[0].physics_dt  # as the in-process runner's t
                block[:, 1:] = rows[:, _TRACE_IDX]
                self._rows.append(block)
            self._check_termination()
        return []

    def _check_termination(self) -> None:
        if self.termination is not None:
            return
        sim, when = self.sim, self._time
        if ended(sim)[0]:  # the runner's rule, so that both give equal trajectories
            end = end_event(sim, 0)
            self.termination = {"when": end.t, "desc": end.message, "code": end.kind}
            if end.with_ is not None:
                self.termination["with"] = end.with_
        elif self.frame_limit is not None and sim.frame_index[0] >= self.frame_limit:
            self.termination = {"when": when, "desc": "the episode's time is up", "code": "timeout"}

    def _on_observations(self, data: Any) -> list[bytes]:
        name, _t = robot_wire.parse_named_request(data, "get_robot_observations")
        self._advance("get_robot_observations")
        start = time.time_ns()
        self._robot_named(name, "get_robot_observations")
        sim = self.sim
        jpg = b""
        if self.robot.simulate_camera:
            k = int(sim.frame_index[0])
            if self._frame is None or self._frame[0] != k:
                self._frame = (k, jpeg.encode(sim.render()[0], self.quality))
            jpg = self._frame[1]
        res = sim.params[0].encoder_resolution
        ticks = wheel_ticks(sim.state[0, [ST.WHEEL_L, ST.WHEEL_R]], res)
        extras = None
        if self.extensions:
            route = sim.routes.info(0, sim.lane[0])
            extras = encode_extras(LanePose.from_row(sim.lane[0])) | {"route": {
                "next_turn": route.next_turn, "stop_distance": float(route.stop_distance),
                "in_intersection": bool(route.in_intersection)}}
        obs = wire.observations_data(jpg, self._time, (float(ticks[0] * res), float(ticks[1] * res)), res, extras)
        return [robot_wire.encode_robot_observations(name, self._time, obs, self._timing(start))]

    def _on_robot_state(self, data: Any) -> list[bytes]:
        name, _t = robot_wire.parse_named_request(data, "get_robot_state")
        self._advance("get_robot_state")
        start = time.time_ns()
        if name in self.parked:
            return [robot_wire.encode_robot_state(name, self._time, self.parked[name], 0.0, 0.0, np.zeros(2),
                                                  wire.DEFAULT_LEDS, None, self._timing(start))]
        self._robot_named(name, "get_robot_state")
        s = self.sim.state[0]
        pose = (float(s[ST.X]), float(s[ST.Y]), float(s[ST.THETA]))
        extras = None
        if self.extensions:
            rows = np.vstack(self._rows) if self._rows else np.zeros((0, len(robot_wire.TRACE_COLUMNS)))
            self._rows = []
            routes = self.sim.routes
            extras = {"pose": list(pose), "v": float(s[ST.V]), "omega": float(s[ST.OMEGA]),
                      "off_road": bool(self.sim.off_road[0]), "collided": bool(self.sim.collided[0]),
                      "trace": {k: rows[:, i].tolist() for i, k in enumerate(robot_wire.TRACE_COLUMNS)},
                      "route": {"active": bool(routes.active), "choices": _plain(routes.choices[0]),
                                "pins": [p for p, _ in self._lanes], "nexts": [n for _, n in self._lanes]}}
            self._lanes = []
        return [robot_wire.encode_robot_state(name, self._time, pose, s[ST.V], s[ST.OMEGA], self.commands,
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
        s = self.sim.state[0]
        bots = {self.robot.robot_name: robot_info_data(
            (float(s[ST.X]), float(s[ST.Y]), float(s[ST.THETA])), s[ST.V], s[ST.OMEGA], self.commands, self.leds)}
        for name, pose in self.parked.items():
            bots[name] = robot_info_data(pose, 0.0, 0.0, (0.0, 0.0), wire.DEFAULT_LEDS)
        return [robot_wire.encode_state_dump(self._time, bots, self.duckies, self._timing(start))]

    def _on_ui_image(self, data: Any) -> list[bytes]:
        if data is not None:
            raise wire.MessageTypeError(f"get_ui_image: data must be null, got {type(data).__name__}")
        self._advance("get_ui_image")
        start = time.time_ns()
        sim = self.sim
        img = top_down(sim.map, sim.state[:1, :3], _UI_PX_PER_TILE, sim.params[0])
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
        p = self.params
        return (f"proxybench simulator node: ONE SIMULATED Duckiebot (not a real robot) behind AIDO's simulator "
                f"protocol. Camera {p.image_width}x{p.image_height} at {p.frame_rate:g} Hz, physics "
                f"{p.physics_rate:g} Hz. Extensions (opt-in with yaml_payload proxybench: true): exact state, "
                f"physics-rate trace and true lane pose.")


def serve_robot(node: RobotNode, data_in: str | int | BinaryIO | None = None,
                data_out: str | int | BinaryIO | None = None, *, exit_on_abort: bool = True) -> int:
    """Serve ``node`` on ``$AIDONODE_DATA_IN`` / ``$AIDONODE_DATA_OUT`` (else stdin/stdout) until EOF."""
    return serve_node(node, data_in, data_out, exit_on_abort=exit_on_abort)
