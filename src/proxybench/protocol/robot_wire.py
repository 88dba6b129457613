"""The robot (simulator) protocol's messages: encoders for both sides and strict parsers.

Field names, nesting and types are AIDO's ``protocol_simulator`` for the DB20 Duckiebot (``aido_schemas``
6.1.1, ``protocol_simulator_DB20_timestamps``): ``SpawnRobot`` with a ``RobotConfiguration`` of
``FriendlyPose`` / ``FriendlyVelocity`` (degrees) and ``dynamics`` / ``dynamics_params``, ``SpawnDuckie``,
``DB20SetRobotCommands``, ``GetRobotObservations`` → ``DB20RobotObservationsWithTimestamp`` whose
``observations`` are exactly the agent protocol's, ``DTSimRobotState`` whose pose and velocity are
NumPy arrays as zuper encodes them (``{data, dtype, shape}``: the SE(2) matrix and the se(2) twist),
``DTSimDuckieState``, ``SimulationState`` with per-robot ``Termination``, ``RobotPerformance``,
``DTSimStateDump``, ``JPGImage``. proxybench additions are optional ``proxybench`` fields that AIDO's
decoder ignores (docs/robot-protocol.md). Like the agent messages in :mod:`.wire`, floats are always
written as CBOR floats, node parsers reject an int where a float is declared, and every error names the
message and field at fault.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from proxybench.domain.events import Termination
from proxybench.domain.lane_pose import LanePose
from proxybench.domain.routes import RouteInfo
from proxybench.protocol import wire
from proxybench.protocol.aido_arrays import ndarray_data, parse_ndarray, pose_of, robot_info_data, se2_matrix
from proxybench.protocol.description import decode_extras
from proxybench.protocol.wire import MessageTypeError, _is_float, _is_number, _need

__all__ = [
    "DEFAULT_DYNAMICS", "TERMINATION_CODES", "TRACE_COLUMNS", "Ending", "RobotInfo", "RobotObservationsData",
    "RobotStateData", "RouteData", "SimState", "SpawnDuckieData", "SpawnRobotData", "encode_clear",
    "encode_duckie_state", "encode_get_robot_interface_description", "encode_get_robot_observations",
    "encode_get_robot_performance", "encode_get_robot_state", "encode_get_sim_state",
    "encode_robot_interface_description", "encode_robot_observations", "encode_robot_performance",
    "encode_robot_state", "encode_set_map", "encode_set_robot_commands", "encode_sim_state", "encode_spawn_robot",
    "encode_state_dump", "encode_step", "encode_ui_image", "parse_dump_state",
    "parse_named_request", "parse_robot_info", "parse_robot_name", "parse_robot_observations",
    "parse_robot_state", "parse_set_map", "parse_set_robot_commands", "parse_sim_state", "parse_spawn_duckie",
    "parse_spawn_robot", "parse_step",
]

#: termination code a robot may report → proxybench's termination (AIDO's out-of-lane / out-of-tile: off road)
TERMINATION_CODES = {"collision": Termination.COLLISION, "off_road": Termination.OFF_ROAD,
                     "timeout": Termination.TIMEOUT, "out-of-lane": Termination.OFF_ROAD,
                     "out-of-tile": Termination.OFF_ROAD}
#: the columns of the proxybench tick trace in ``robot_state.state.proxybench.trace``
TRACE_COLUMNS = ("t", "x", "y", "theta", "v", "omega", "pwm_left", "pwm_right")
_ZERO_VELOCITY = {"x": 0.0, "y": 0.0, "theta_deg": 0.0}
#: ``spawn_robot.dynamics`` the caller sends: the robot's own dynamics (a robot node's θ is fixed at its start)
DEFAULT_DYNAMICS = "DB18"


def _str(x: Any) -> bool:
    return type(x) is str


def _bool(x: Any) -> bool:
    return type(x) is bool


def _map(x: Any) -> bool:
    return isinstance(x, dict)


# ------------------------------------------------------------------------------------- caller → node
def encode_clear() -> bytes:
    return wire.encode_topic("clear", None)


def encode_set_map(map_yaml: str) -> bytes:
    return wire.encode_topic("set_map", {"map_data": str(map_yaml)})


def encode_spawn_robot(robot_name: str, pose: tuple[float, float, float], *, simulate_camera: bool = True,
                       color: str = "red", dynamics: str = DEFAULT_DYNAMICS, dynamics_params: dict | None = None
                       ) -> bytes:
    """AIDO's ``SpawnRobot`` of the playable robot at rest at ``pose`` (x [m], y [m], θ [rad])."""
    x, y, theta = (float(v) for v in pose)
    config = {"pose": {"x": x, "y": y, "theta_deg": math.degrees(theta)}, "velocity": dict(_ZERO_VELOCITY)}
    return wire.encode_topic("spawn_robot", {"playable": True, "owned_by_player": True, "robot_name": robot_name,
                                             "configuration": config, "dynamics": str(dynamics),
                                             "dynamics_params": dict(dynamics_params or {}), "color": color,
                                             "simulate_camera": bool(simulate_camera)})


def encode_get_robot_interface_description(robot_name: str) -> bytes:
    return wire.encode_topic("get_robot_interface_description", robot_name)


def encode_set_robot_commands(robot_name: str, t_effective: float, left: float, right: float) -> bytes:
    commands = {"wheels": {"motor_left": float(left), "motor_right": float(right)}, "LEDS": wire.DEFAULT_LEDS}
    return wire.encode_topic("set_robot_commands", {"robot_name": robot_name, "t_effective": float(t_effective),
                                                    "commands": commands})


def encode_step(until: float) -> bytes:
    return wire.encode_topic("step", {"until": float(until)})


def encode_get_robot_observations(robot_name: str, t_effective: float) -> bytes:
    return wire.encode_topic("get_robot_observations", {"robot_name": robot_name, "t_effective": float(t_effective)})


def encode_get_robot_state(robot_name: str, t_effective: float) -> bytes:
    return wire.encode_topic("get_robot_state", {"robot_name": robot_name, "t_effective": float(t_effective)})


def encode_get_sim_state() -> bytes:
    return wire.encode_topic("get_sim_state", None)


def encode_get_robot_performance(robot_name: str) -> bytes:
    return wire.encode_topic("get_robot_performance", robot_name)


# ------------------------------------------------------------------------------- node: parse inputs
def parse_set_map(data: Any) -> str:
    return _need(data, "map_data", _str, "a string (map YAML)", "set_map")


@dataclass(frozen=True, slots=True)
class SpawnRobotData:
    """A decoded ``spawn_robot``; ``pose`` (x [m], y [m], θ [rad]) is None when ``configuration`` is null
    (accepted from older proxybench callers: the start is then drawn from the episode seed)."""

    robot_name: str
    pose: tuple[float, float, float] | None
    playable: bool = True
    owned_by_player: bool = True
    color: str = "red"
    simulate_camera: bool = True
    dynamics: str = DEFAULT_DYNAMICS
    dynamics_params: dict | None = None


@dataclass(frozen=True, slots=True)
class SpawnDuckieData:
    """A decoded ``spawn_duckie``: a duckie standing at ``pose`` (x [m], y [m], θ [rad])."""

    name: str
    color: str
    pose: tuple[float, float, float]


def _friendly(data: Any, topic: str) -> tuple[float, float, float]:
    x, y, th = (_need(data, k, _is_float, "a float", topic) for k in ("x", "y", "theta_deg"))
    if not all(map(math.isfinite, (x, y, th))):
        raise MessageTypeError(f"{topic}: x, y, theta_deg must be finite, got {x!r}, {y!r}, {th!r}")
    return x, y, th


def parse_spawn_robot(data: Any) -> SpawnRobotData:
    name = _need(data, "robot_name", _str, "a string", "spawn_robot")
    playable = _need(data, "playable", _bool, "a boolean", "spawn_robot")
    owned = data.get("owned_by_player", True)
    color = data.get("color", "red")
    camera = data.get("simulate_camera", True)
    dynamics = data.get("dynamics", DEFAULT_DYNAMICS)
    dynamics_params = data.get("dynamics_params")
    for key, value, check, what in (("owned_by_player", owned, _bool, "a boolean"), ("color", color, _str, "a string"),
                                    ("simulate_camera", camera, _bool, "a boolean"),
                                    ("dynamics", dynamics, _str, "a string"),
                                    ("dynamics_params", dynamics_params, lambda v: v is None or _map(v), "a map")):
        if not check(value):
            raise MessageTypeError(f"spawn_robot: field {key!r} must be {what}, got {type(value).__name__}")
    if "configuration" not in data:
        raise MessageTypeError("spawn_robot: missing field 'configuration' (a RobotConfiguration, or null)")
    config, pose = data["configuration"], None
    if config is not None:
        if not _map(config):
            raise MessageTypeError("spawn_robot: field 'configuration' must be a map or null")
        x, y, th = _friendly(_need(config, "pose", _map, "a map", "spawn_robot.configuration"),
                             "spawn_robot.configuration.pose")
        vel = _friendly(_need(config, "velocity", _map, "a map", "spawn_robot.configuration"),
                        "spawn_robot.configuration.velocity")
        if any(vel):
            raise MessageTypeError(f"spawn_robot.configuration.velocity must be zero (robots start at rest), "
                                   f"got {vel}")
        pose = (x, y, math.radians(th))
    return SpawnRobotData(name, pose, playable, owned, color, camera, dynamics, dynamics_params)


def parse_spawn_duckie(data: Any) -> SpawnDuckieData:
    name = _need(data, "name", _str, "a string", "spawn_duckie")
    color = _need(data, "color", _str, "a string", "spawn_duckie")
    x, y, th = _friendly(_need(data, "pose", _map, "a map (FriendlyPose)", "spawn_duckie"), "spawn_duckie.pose")
    return SpawnDuckieData(name, color, (x, y, math.radians(th)))


def parse_dump_state(data: Any) -> None:
    """``dump_state`` carries an empty ``DumpState`` (``{}``, perhaps with its ``$schema``), or null."""
    if data is not None and not _map(data):
        raise MessageTypeError(f"dump_state: data must be a map (DumpState) or null, got {type(data).__name__}")


def parse_robot_name(data: Any, topic: str) -> str:
    if not _str(data):
        raise MessageTypeError(f"{topic}: data must be a robot name (string), got {type(data).__name__}")
    return data


def parse_named_request(data: Any, topic: str, key: str = "robot_name") -> tuple[str, float]:
    """(robot_name, t_effective) of get_robot_observations / get_robot_state (``key="duckie_name"``:
    get_duckie_state)."""
    name = _need(data, key, _str, "a string", topic)
    t = _need(data, "t_effective", _is_float, "a float", topic)
    return name, t


def parse_set_robot_commands(data: Any) -> tuple[str, float, np.ndarray]:
    """(robot_name, t_effective, wheel PWM (left, right)); PWM must be finite and in [-1, 1]."""
    name, t = parse_named_request(data, "set_robot_commands")
    commands = _need(data, "commands", _map, "a map (DB20Commands)", "set_robot_commands")
    wheels = _need(commands, "wheels", _map, "a map", "set_robot_commands.commands")
    out = np.empty(2)
    for i, key in enumerate(("motor_left", "motor_right")):
        v = _need(wheels, key, _is_float, "a float", "set_robot_commands.commands.wheels")
        if not math.isfinite(v) or not -1.0 <= v <= 1.0:
            raise MessageTypeError(f"set_robot_commands.commands.wheels: {key} = {v!r} is not a finite number "
                                   f"in [-1, 1]")
        out[i] = v
    return name, t, out


def parse_step(data: Any) -> float:
    until = _need(data, "until", _is_float, "a float", "step")
    if not math.isfinite(until):
        raise MessageTypeError(f"step: until = {until!r} is not finite")
    return until


# ------------------------------------------------------------------------------ node: encode outputs
def encode_robot_observations(robot_name: str, t_effective: float, obs_data: dict, timing: dict) -> bytes:
    """``obs_data``: the agent protocol's observations map (camera, odometry, optional proxybench)."""
    data = {"robot_name": robot_name, "t_effective": float(t_effective), "observations": obs_data}
    return wire.encode_topic("robot_observations", wire.canonical(data), timing)


def encode_robot_state(robot_name: str, t_effective: float, pose: tuple[float, float, float], v: float,
                       omega: float, pwm: np.ndarray, leds: dict, extras: dict | None, timing: dict) -> bytes:
    """AIDO's ``DTSimRobotState`` (pose as SE(2), velocity as se(2)); ``extras``: the proxybench extension."""
    state: dict[str, Any] = robot_info_data(pose, v, omega, pwm, leds)
    if extras is not None:
        state["proxybench"] = extras
    data = {"robot_name": robot_name, "t_effective": float(t_effective), "state": state}
    return wire.encode_topic("robot_state", wire.canonical(data), timing)


def encode_duckie_state(duckie_name: str, t_effective: float, pose: tuple[float, float, float], timing: dict) -> bytes:
    """AIDO's ``DTSimDuckieState`` of a duckie standing at ``pose``."""
    state = {"pose": ndarray_data(se2_matrix(*pose)), "velocity": ndarray_data(np.zeros((3, 3)))}
    data = {"duckie_name": duckie_name, "t_effective": float(t_effective), "state": state}
    return wire.encode_topic("duckie_state", wire.canonical(data), timing)


def encode_state_dump(t_effective: float, duckiebots: dict[str, dict], duckies: dict[str, tuple[float, float, float]],
                      timing: dict) -> bytes:
    """AIDO's ``DTSimStateDump``: ``duckiebots`` name → :func:`robot_info_data`, ``duckies`` name → pose."""
    zero = ndarray_data(np.zeros((3, 3)))
    state = {"t_effective": float(t_effective), "duckiebots": duckiebots,
             "duckies": {k: {"pose": ndarray_data(se2_matrix(*p)), "velocity": zero} for k, p in duckies.items()}}
    return wire.encode_topic("state_dump", wire.canonical({"state": state}), timing)


def encode_ui_image(jpg: bytes, timing: dict) -> bytes:
    return wire.encode_topic("ui_image", {"jpg_data": bytes(jpg)}, timing)


def encode_sim_state(done: bool, terminations: dict[str, dict | None], timing: dict) -> bytes:
    return wire.encode_topic("sim_state", wire.canonical({"done": bool(done), "terminations": terminations}), timing)


def encode_robot_performance(robot_name: str, t_effective: float, metrics: dict[str, tuple[bool, float, str]],
                             timing: dict) -> bytes:
    """``metrics``: name → (higher_is_better, cumulative_value, description)."""
    perf = {k: {"higher_is_better": hib, "cumulative_value": float(v), "description": d}
            for k, (hib, v, d) in metrics.items()}
    data = {"robot_name": robot_name, "t_effective": float(t_effective), "performance": {"metrics": perf}}
    return wire.encode_topic("robot_performance", wire.canonical(data), timing)


def encode_robot_interface_description(robot_name: str, observations: dict, commands: dict, info: dict,
                                       timing: dict) -> bytes:
    data = {"robot_name": robot_name, "observations": observations, "commands": commands, "proxybench": info}
    return wire.encode_topic("robot_interface_description", wire.canonical(data), timing)


# ------------------------------------------------------------------------------ caller: parse outputs
@dataclass(frozen=True, slots=True)
class RobotObservationsData:
    """A decoded ``robot_observations``: the observations as the agent protocol carries them, and the
    ground truth of the proxybench extension when the robot sent it."""

    robot_name: str
    t_effective: float
    observations: wire.ObservationsData
    raw: dict
    lane_pose: LanePose | None = None
    route: RouteInfo | None = None


def parse_robot_observations(data: Any) -> RobotObservationsData:
    name = _need(data, "robot_name", _str, "a string", "robot_observations")
    t = _need(data, "t_effective", _is_number, "a number", "robot_observations")
    obs = _need(data, "observations", _map, "a map", "robot_observations")
    try:
        parsed = wire.parse_observations(obs)
        lane = decode_extras(parsed.extras)
    except MessageTypeError as exc:
        raise MessageTypeError(f"robot_observations.{exc}") from exc  # robot_observations.observations.camera: …
    except TypeError as exc:  # a malformed lane pose
        raise MessageTypeError(f"robot_observations.{exc}") from exc
    route = None
    if (parsed.extras or {}).get("route") is not None:
        r, where = parsed.extras["route"], "robot_observations.observations.proxybench.route"
        turn = _need(r, "next_turn", lambda v: v is None or _str(v), "a string or null", where)
        stop = _need(r, "stop_distance", _is_number, "a number", where)
        inside = _need(r, "in_intersection", _bool, "a boolean", where)
        route = RouteInfo(turn, float(stop), inside)
    return RobotObservationsData(name, float(t), parsed, obs, lane, route)


@dataclass(frozen=True, slots=True)
class RobotStateData:
    """A decoded ``robot_state``: pose (x [m], y [m], θ [rad]), body velocity v [m/s], ω [rad/s], applied
    PWM; ``trace`` (column → array) and exact values only when the proxybench extension was sent."""

    robot_name: str
    t_effective: float
    pose: tuple[float, float, float]
    v: float
    omega: float
    pwm: tuple[float, float]
    trace: dict[str, np.ndarray] | None = None
    off_road: bool | None = None
    collided: bool | None = None
    route: RouteData | None = None


@dataclass(frozen=True, slots=True)
class RouteData:
    """The route part of the proxybench state: whether the map has choices to make, the choices made so far,
    and per frame stepped since the previous state the pinned and next lane before the step (-1: none)."""

    active: bool
    choices: list
    pins: list[int]
    nexts: list[int]


def _numbers(value: Any, where: str) -> np.ndarray:
    if not isinstance(value, list) or not all(_is_number(v) for v in value):
        raise MessageTypeError(f"{where} must be a list of numbers")
    return np.asarray(value, dtype=np.float64)


def _state_motion(state: dict) -> tuple[tuple[float, float, float], float, float]:
    """(pose, v, ω) of a ``DTSimRobotInfo``: AIDO's SE(2) / se(2) arrays, or ``FriendlyPose`` /
    ``FriendlyVelocity`` maps (degrees), which some bridges send."""
    pose_m = _need(state, "pose", _map, "a map", "robot_state.state")
    vel = _need(state, "velocity", _map, "a map", "robot_state.state")
    if "shape" in pose_m or "data" in pose_m:
        pose = pose_of(parse_ndarray(pose_m, "robot_state.state.pose", (3, 3)))
        twist = parse_ndarray(vel, "robot_state.state.velocity", (3, 3))
        return pose, float(twist[0, 2]), float(twist[1, 0])
    x, y, th = (float(_need(pose_m, k, _is_number, "a number", "robot_state.state.pose"))
                for k in ("x", "y", "theta_deg"))
    v, w = (float(_need(vel, k, _is_number, "a number", "robot_state.state.velocity")) for k in ("x", "theta_deg"))
    return (x, y, math.radians(th)), v, math.radians(w)


def parse_robot_state(data: Any) -> RobotStateData:
    name = _need(data, "robot_name", _str, "a string", "robot_state")
    t = _need(data, "t_effective", _is_number, "a number", "robot_state")
    state = _need(data, "state", _map, "a map", "robot_state")
    pose, v, omega = _state_motion(state)
    pwm_m = _need(state, "pwm", _map, "a map", "robot_state.state")
    pwm = tuple(float(_need(pwm_m, k, _is_number, "a number", "robot_state.state.pwm"))
                for k in ("motor_left", "motor_right"))
    extras = state.get("proxybench")
    if extras is None:
        return RobotStateData(name, float(t), pose, v, omega, pwm)
    where = "robot_state.state.proxybench"
    if not _map(extras):
        raise MessageTypeError(f"{where} must be a map")
    exact = _numbers(_need(extras, "pose", lambda p: isinstance(p, list) and len(p) == 3, "[x, y, theta]", where),
                     where + ".pose")
    v = float(_need(extras, "v", _is_number, "a number", where))
    omega = float(_need(extras, "omega", _is_number, "a number", where))
    flags = [_need(extras, k, _bool, "a boolean", where) for k in ("off_road", "collided")]
    raw = _need(extras, "trace", _map, "a map", where)
    trace = {k: _numbers(_need(raw, k, lambda c: True, "a list", where + ".trace"), f"{where}.trace.{k}")
             for k in TRACE_COLUMNS}
    if len({c.size for c in trace.values()}) != 1:
        raise MessageTypeError(f"{where}.trace: columns of different lengths "
                               f"{ {k: c.size for k, c in trace.items()} }")
    route = None
    if extras.get("route") is not None:
        r = _need(extras, "route", _map, "a map", where)
        active = _need(r, "active", _bool, "a boolean", where + ".route")
        choices = _need(r, "choices", lambda c: isinstance(c, list), "a list", where + ".route")
        lanes = [_need(r, k, lambda c: isinstance(c, list) and all(type(v) is int for v in c), "a list of integers",
                       where + ".route") for k in ("pins", "nexts")]
        if len(lanes[0]) != len(lanes[1]):
            raise MessageTypeError(f"{where}.route: pins and nexts of different lengths")
        route = RouteData(active, choices, *lanes)
    return RobotStateData(name, float(t), (float(exact[0]), float(exact[1]), float(exact[2])), v, omega, pwm,
                          trace, flags[0], flags[1], route)


@dataclass(frozen=True, slots=True)
class Ending:
    """Why and when a robot's episode ended: ``termination`` is proxybench's name for the reported code
    (:data:`TERMINATION_CODES`), ``desc`` the robot's words, ``when`` [s]; ``hit``: what it collided with."""

    termination: Termination
    desc: str
    when: float
    hit: str | None = None


@dataclass(frozen=True, slots=True)
class SimState:
    """A decoded ``sim_state``: robot name → its :class:`Ending`, or None while it drives on."""

    done: bool
    terminations: dict[str, Ending | None]


def parse_sim_state(data: Any) -> SimState:
    done = _need(data, "done", _bool, "a boolean", "sim_state")
    raw = _need(data, "terminations", _map, "a map", "sim_state")
    terms: dict[str, Ending | None] = {}
    for robot, term in raw.items():
        where = f"sim_state.terminations[{robot!r}]"
        if term is None:
            terms[str(robot)] = None
            continue
        code = _need(term, "code", _str, "a string", where)
        if code not in TERMINATION_CODES:
            raise MessageTypeError(f"{where}.code = {code!r} is not one of {sorted(TERMINATION_CODES)}")
        code = TERMINATION_CODES[code]
        desc = _need(term, "desc", _str, "a string", where)
        when = _need(term, "when", _is_number, "a number", where)
        hit = term.get("with")
        if hit is not None and not _str(hit):
            raise MessageTypeError(f"{where}: field 'with' must be a string")
        terms[str(robot)] = Ending(code, desc, float(when), hit)
    return SimState(done, terms)


@dataclass(frozen=True, slots=True)
class RobotInfo:
    """What a robot node says it is (``robot_interface_description.proxybench``), or what the caller assumes
    when it says nothing (a stock AIDO simulator, a bridge without the extension: :attr:`reported` False).

    ``kind``: "simulation" for a simulator node, "robot" for a physical robot's bridge, "unreported";
    ``frame_rate`` [Hz]: camera frames per second, the period the caller steps by; ``physics_rate`` [Hz]:
    trace samples per second (None: no trace); ``wheel_distance`` [m]; ``params``: the domain parameters θ.
    """

    kind: str
    frame_rate: float
    physics_rate: float | None
    wheel_distance: float
    params: dict
    raw: dict
    reported: bool = True


#: the Duckiebot's wheel distance [m] (DB18 / DB21), assumed when a robot does not report its own
DEFAULT_WHEEL_DISTANCE = 0.102


def parse_robot_info(data: Any, default_frame_rate: float = 15.0) -> RobotInfo:
    """The robot's self-description; without the optional ``proxybench`` field (AIDO's
    ``RobotInterfaceDescription`` has none), a robot of kind "unreported" stepped at ``default_frame_rate``."""
    if not _map(data):
        raise MessageTypeError(f"robot_interface_description: data must be a map, got {type(data).__name__}")
    info = data.get("proxybench")
    if info is None:
        return RobotInfo("unreported", float(default_frame_rate), None, DEFAULT_WHEEL_DISTANCE, {}, {}, False)
    where = "robot_interface_description.proxybench"
    if not _map(info):
        raise MessageTypeError(f"{where} must be a map (what the robot is; see docs/robot-protocol.md)")
    kind = _need(info, "kind", _str, "a string", where)
    rate = float(_need(info, "frame_rate", _is_number, "a number", where))
    if not (math.isfinite(rate) and rate > 0):
        raise MessageTypeError(f"{where}: frame_rate must be a positive number [Hz], got {rate!r}")
    physics = info.get("physics_rate")
    if physics is not None and not (_is_number(physics) and physics > 0):
        raise MessageTypeError(f"{where}: physics_rate must be a positive number [Hz] or absent")
    wheel = info.get("wheel_distance", DEFAULT_WHEEL_DISTANCE)
    if not (_is_number(wheel) and wheel > 0):
        raise MessageTypeError(f"{where}: wheel_distance must be a positive number [m]")
    params = info.get("params") or {}
    if not _map(params):
        raise MessageTypeError(f"{where}: params must be a map")
    return RobotInfo(kind, rate, None if physics is None else float(physics), float(wheel), params, info)
