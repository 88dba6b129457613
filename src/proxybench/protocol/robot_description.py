"""A robot node's answer to ``wrapper.describe_protocol``: the simulator protocol as JSON schemas.

The types and names are those of AIDO's ``protocol_simulator`` particularised for the DB20 Duckiebot
(``aido_schemas``: ``DB20SetRobotCommands``, ``DB20RobotObservations`` with timestamps, ``DTSimRobotState``,
``SimulationState``, ``RobotPerformance``), written the way zuper writes dataclass schemas (see
:mod:`.description`). The language is the part of AIDO's simulator language a single-robot node speaks.
proxybench additions are optional properties named ``proxybench`` (never in ``order`` nor ``required``), so
the AIDO types are unchanged; docs/robot-protocol.md describes them.
"""

from __future__ import annotations

from typing import Any

from proxybench.protocol.description import (
    _S,
    _any,
    _commands,
    _episode_start,
    _extension_schema,
    _float,
    _meta_protocol,
    _obj,
    _observations,
    _rgb,
    _t,
)
from proxybench.protocol.language import ROBOT_LANGUAGE
from proxybench.protocol.wire import canonical

__all__ = ["robot_protocol_description"]

_SIM = "aido_schemas.protocol_simulator"
_SCHEMAS = "aido_schemas.schemas"
_PB = "proxybench.protocol"


def _nullable(schema: dict) -> dict:
    return {"anyOf": [schema, _t("null")], "$schema": _S}


def _friendly(name: str, description: str) -> dict:
    return _obj(name, _SIM, {"x": _float(), "y": _float(), "theta_deg": _float()}, ["x", "y", "theta_deg"],
                description)


def _named_time(name: str, module: str = _SIM) -> dict:
    return _obj(name, module, {"robot_name": _t("string"), "t_effective": _float()}, ["robot_name", "t_effective"])


def _spawn_robot() -> dict:
    pose = _friendly("FriendlyPose", "Map-frame position [m] and heading [deg].")
    vel = _friendly("FriendlyVelocity", "Body-frame velocity: forward x, lateral y [m/s], yaw rate [deg/s].")
    config = _obj("RobotConfiguration", _SIM, {"pose": pose, "velocity": vel}, ["pose", "velocity"])
    order = ["playable", "owned_by_player", "robot_name", "configuration", "color", "simulate_camera"]
    props = {"playable": _t("boolean"), "owned_by_player": _t("boolean"), "robot_name": _t("string"),
             "configuration": _nullable(config), "color": {**_t("string"), "default": "red"},
             "simulate_camera": {**_t("boolean"), "default": True}}
    spawn = _obj("SpawnRobot", _SIM, props, order,
                 "configuration null (proxybench): the start pose is drawn from the episode seed.")
    spawn["required"] = ["configuration", "playable", "robot_name"]
    return spawn


def _pwm() -> dict:
    return _obj("PWMCommands", _SCHEMAS, {"motor_left": _float(), "motor_right": _float()},
                ["motor_left", "motor_right"], "\n    PWM commands are floats between -1 and 1.\n    ")


def _robot_state() -> dict:
    leds_order = ["center", "front_left", "front_right", "back_left", "back_right"]
    leds = _obj("LEDSCommands", _SCHEMAS, {k: _rgb() for k in leds_order}, leds_order)
    trace = _obj("ProxybenchTrace", _PB, {k: {"type": "array", "items": _float(), "$schema": _S}
                                          for k in ("t", "x", "y", "theta", "v", "omega", "pwm_left", "pwm_right")},
                 ["t", "x", "y", "theta", "v", "omega", "pwm_left", "pwm_right"],
                 "Every physics tick since the previous robot_state: t [s], x, y [m], theta [rad], v [m/s], "
                 "omega [rad/s], applied PWM.")
    extra = _obj("ProxybenchRobotState", _PB,
                 {"pose": {"type": "array", "items": _float(), "$schema": _S}, "v": _float(), "omega": _float(),
                  "off_road": _t("boolean"), "collided": _t("boolean"), "trace": trace},
                 ["pose", "v", "omega", "off_road", "collided", "trace"],
                 "proxybench extension (requested in episode_start): exact state in radians and the tick trace.")
    info = _obj("DTSimRobotInfo", _SCHEMAS,
                {"pose": _friendly("FriendlyPose", "Map-frame position [m] and heading [deg]."),
                 "velocity": _friendly("FriendlyVelocity", "Body-frame velocity [m/s] and yaw rate [deg/s]."),
                 "pwm": _pwm(), "leds": leds}, ["pose", "velocity", "pwm", "leds"])
    info["properties"]["proxybench"] = extra
    return _obj("DTSimRobotState", _SCHEMAS,
                {"robot_name": _t("string"), "t_effective": _float(), "state": info},
                ["robot_name", "t_effective", "state"])


def _sim_state() -> dict:
    term = _obj("Termination", _SIM, {"when": _float(), "desc": _t("string"), "code": _t("string")},
                ["when", "desc", "code"], "code (proxybench): collision | off_road | timeout")
    terms = {"type": "object", "title": "Dict[str,Optional[Termination]]", "$schema": _S,
             "additionalProperties": _nullable(term)}
    return _obj("SimulationState", _SIM, {"done": _t("boolean"), "terminations": terms}, ["done", "terminations"],
                "\n    Returns the simulation state.\n\n    done: Whether the simulation should be terminated.\n    ")


def _performance() -> dict:
    metric = _obj("Metric", _SIM, {"higher_is_better": _t("boolean"), "cumulative_value": _float(),
                                   "description": _t("string")},
                  ["higher_is_better", "cumulative_value", "description"])
    metrics = _obj("PerformanceMetrics", _SIM, {"metrics": {"type": "object", "title": "Dict[str,Metric]",
                                                            "$schema": _S, "additionalProperties": metric}},
                   ["metrics"])
    return _obj("RobotPerformance", _SIM, {"robot_name": _t("string"), "t_effective": _float(),
                                           "performance": metrics}, ["robot_name", "t_effective", "performance"])


def _interface() -> dict:
    info = _obj("ProxybenchRobotInfo", _PB,
                {"kind": _t("string"), "frame_rate": _float(), "physics_rate": _float(),
                 "wheel_distance": _float(), "encoder_resolution": _float(), "image_width": _t("integer"),
                 "image_height": _t("integer"), "params": _any()},
                ["kind", "frame_rate", "physics_rate", "wheel_distance", "encoder_resolution", "image_width",
                 "image_height", "params"],
                "What the robot is: kind (simulation | robot), camera frame rate [Hz], physics rate [Hz], "
                "wheel distance [m], encoder step [rad], image size [px], domain parameters.")
    typ = {"$ref": _S, "title": "type"}
    out = _obj("RobotInterfaceDescription", _SIM, {"robot_name": _t("string"), "observations": typ,
                                                   "commands": dict(typ)}, ["robot_name", "observations", "commands"])
    out["properties"]["proxybench"] = info
    return out


def _data_protocol() -> dict[str, Any]:
    observations = _observations(False)
    observations["properties"]["proxybench"] = _extension_schema()
    robot_obs = _obj("DB20RobotObservations", _SCHEMAS, {"robot_name": _t("string"), "t_effective": _float(),
                                                         "observations": observations},
                     ["robot_name", "t_effective", "observations"])
    set_commands = _obj("DB20SetRobotCommands", _SCHEMAS, {"robot_name": _t("string"), "t_effective": _float(),
                                                           "commands": _commands()},
                        ["robot_name", "t_effective", "commands"])
    return {
        "inputs": {
            "seed": _t("integer"), "clear": _t("null"),
            "set_map": _obj("DTSetMap", _SCHEMAS, {"map_data": _t("string")}, ["map_data"]),
            "spawn_robot": _spawn_robot(), "get_robot_interface_description": _t("string"),
            "get_robot_performance": _t("string"), "get_sim_state": _t("null"), "episode_start": _episode_start(),
            "step": _obj("Step", _SIM, {"until": _float()}, ["until"]), "set_robot_commands": set_commands,
            "get_robot_observations": _named_time("GetRobotObservations"),
            "get_robot_state": _named_time("GetRobotState"),
        },
        "outputs": {"robot_observations": robot_obs, "robot_state": _robot_state(), "sim_state": _sim_state(),
                    "robot_performance": _performance(), "robot_interface_description": _interface()},
        "language": ROBOT_LANGUAGE,
        "description": "Particularization for DB20 observations and commands and timestamps (one robot).",
    }


def robot_protocol_description() -> dict:
    """The ``protocol_description`` data of a robot node."""
    return canonical({"data": _data_protocol(), "meta": _meta_protocol()})
