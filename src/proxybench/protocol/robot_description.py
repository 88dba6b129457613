"""A robot node's answer to ``wrapper.describe_protocol``: AIDO's simulator protocol for the DB20, exactly.

What a stock AIDO simulator node answers (``aido_schemas.protocol_simulator_DB20_timestamps`` with the
zuper-nodes meta protocol, written the way zuper writes dataclass schemas; see :mod:`.description`),
so that AIDO's experiment manager, which checks a simulator's description against
``protocol_simulator_DB20``, accepts a proxybench robot node. The test
``tests/test_robot_aido_conformance.py`` compares it with the description AIDO's own libraries produce.
proxybench's extensions (docs/robot-protocol.md §3) are *not* declared: they are asked for in
``episode_start.yaml_payload`` and are optional fields that AIDO's decoder ignores.
"""

from __future__ import annotations

from typing import Any

from proxybench.protocol.description import (
    _S,
    _any,
    _commands,
    _episode_start,
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


def _dict_of(title: str, value: dict) -> dict:
    return {"type": "object", "title": f"Dict[str,{title}]", "$schema": _S, "properties": {"$schema": {}},
            "additionalProperties": value}


def _with_default(kind: str, default: Any) -> dict:
    return {"anyOf": [_t(kind)], "$schema": _S, "default": default}


def _ndarray() -> dict:
    """How zuper describes a ``numpy.ndarray`` field: ``{data: bytes, dtype, shape}``."""
    return {"type": "object", "title": "numpy", "$schema": _S,
            "properties": {"data": {"type": "string", "title": "bytes", "$schema": _S}, "dtype": {}, "shape": {}}}


def _friendly(name: str) -> dict:
    return _obj(name, _SIM, {"x": _float(), "y": _float(), "theta_deg": _float()}, ["x", "y", "theta_deg"])


def _named_time(name: str, who: str = "robot_name") -> dict:
    return _obj(name, _SIM, {who: _t("string"), "t_effective": _float()}, [who, "t_effective"])


def _spawn_robot() -> dict:
    config = _obj("RobotConfiguration", _SIM, {"pose": _friendly("FriendlyPose"),
                                              "velocity": _friendly("FriendlyVelocity")}, ["pose", "velocity"])
    order = ["playable", "owned_by_player", "robot_name", "configuration", "dynamics", "dynamics_params", "color",
             "simulate_camera"]
    props = {"playable": _t("boolean"), "owned_by_player": _t("boolean"), "robot_name": _t("string"),
             "configuration": config, "dynamics": _t("string"), "dynamics_params": _dict_of("Any", _any()),
             "color": _with_default("string", "red"), "simulate_camera": _with_default("boolean", True)}
    spawn = _obj("SpawnRobot", _SIM, props, order)
    spawn["required"] = sorted(order[:6])
    return spawn


def _robot_info() -> dict:
    pwm = _obj("PWMCommands", _SCHEMAS, {"motor_left": _float(), "motor_right": _float()},
               ["motor_left", "motor_right"], "\n    PWM commands are floats between -1 and 1.\n    ")
    leds_order = ["center", "front_left", "front_right", "back_left", "back_right"]
    leds = _obj("LEDSCommands", _SCHEMAS, {k: _rgb() for k in leds_order}, leds_order)
    return _obj("DTSimRobotInfo", _SCHEMAS, {"pose": _ndarray(), "velocity": _ndarray(), "pwm": pwm, "leds": leds},
                ["pose", "velocity", "pwm", "leds"])


def _duckie_info() -> dict:
    return _obj("DTSimDuckieInfo", _SCHEMAS, {"pose": _ndarray(), "velocity": _ndarray()}, ["pose", "velocity"])


def _sim_state() -> dict:
    term = _obj("Termination", _SIM, {"when": _float(), "desc": _t("string"), "code": _t("string")},
                ["when", "desc", "code"])
    terms = _dict_of("Optional[Termination]", {"anyOf": [term, _t("null")], "$schema": _S})
    return _obj("SimulationState", _SIM, {"done": _t("boolean"), "terminations": terms}, ["done", "terminations"],
                "\n    Returns the simulation state.\n\n    done: Whether the simulation should be terminated.\n    "
                "done_why: Human-readable short message.\n    done_code: Short string to use as code for "
                "statistics.\n    ")


def _performance() -> dict:
    metric = _obj("Metric", _SIM, {"higher_is_better": _t("boolean"), "cumulative_value": _float(),
                                   "description": _t("string")},
                  ["higher_is_better", "cumulative_value", "description"])
    metrics = _obj("PerformanceMetrics", _SIM, {"metrics": _dict_of("Metric", metric)}, ["metrics"],
                   '\n    Performance metrics for an agent.\n\n    By convention there will be one called "reward" '
                   "for RL tasks.\n\n    Note that the values are *cumulative* to make it possible to have\n    a "
                   "sampling-invariant behavior.\n    ")
    return _obj("RobotPerformance", _SIM, {"robot_name": _t("string"), "t_effective": _float(),
                                           "performance": metrics}, ["robot_name", "t_effective", "performance"])


def _jpg() -> dict:
    return _obj("JPGImage", _SIM, {"jpg_data": {"type": "string", "title": "bytes", "$schema": _S}}, ["jpg_data"],
                "\n    An image in JPG format.\n\n    jpg_data: Bytes of a JPG file\n    ")


def _outputs() -> dict[str, Any]:
    robot_obs = _obj("DB20RobotObservationsWithTimestamp", _SCHEMAS,
                     {"robot_name": _t("string"), "t_effective": _float(), "observations": _observations(False)},
                     ["robot_name", "t_effective", "observations"])
    typ = {"$ref": _S, "title": "type"}
    interface = _obj("RobotInterfaceDescription", _SIM, {"robot_name": _t("string"), "observations": typ,
                                                         "commands": dict(typ)},
                     ["robot_name", "observations", "commands"])
    sim = _obj("DTSimState", _SCHEMAS, {"t_effective": _float(),
                                        "duckiebots": _dict_of("DTSimRobotInfo", _robot_info()),
                                        "duckies": _dict_of("DTSimDuckieInfo", _duckie_info())},
               ["t_effective", "duckiebots", "duckies"])
    return {
        "robot_observations": robot_obs,
        "robot_state": _obj("DTSimRobotState", _SCHEMAS, {"robot_name": _t("string"), "t_effective": _float(),
                                                          "state": _robot_info()},
                            ["robot_name", "t_effective", "state"]),
        "duckie_state": _obj("DTSimDuckieState", _SCHEMAS, {"duckie_name": _t("string"), "t_effective": _float(),
                                                            "state": _duckie_info()},
                             ["duckie_name", "t_effective", "state"]),
        "robot_performance": _performance(), "robot_interface_description": interface, "sim_state": _sim_state(),
        "state_dump": _obj("DTSimStateDump", _SCHEMAS, {"state": sim}, ["state"]), "ui_image": _jpg(),
    }


def _data_protocol() -> dict[str, Any]:
    set_commands = _obj("DB20SetRobotCommands", _SCHEMAS, {"robot_name": _t("string"), "t_effective": _float(),
                                                           "commands": _commands()},
                        ["robot_name", "t_effective", "commands"])
    return {
        "inputs": {
            "seed": _t("integer"), "clear": _t("null"),
            "set_map": _obj("DTSetMap", _SCHEMAS, {"map_data": _t("string")}, ["map_data"]),
            "spawn_robot": _spawn_robot(),
            "spawn_duckie": _obj("SpawnDuckie", _SIM, {"name": _t("string"), "color": _t("string"),
                                                       "pose": _friendly("FriendlyPose")}, ["name", "color", "pose"]),
            "get_robot_interface_description": _t("string"), "get_robot_performance": _t("string"),
            "get_sim_state": _t("null"), "episode_start": _episode_start(),
            "step": _obj("Step", _SIM, {"until": _float()}, ["until"]), "set_robot_commands": set_commands,
            "get_robot_observations": _named_time("GetRobotObservations"),
            "get_robot_state": _named_time("GetRobotState"),
            "get_duckie_state": _named_time("GetDuckieState", "duckie_name"),
            "get_ui_image": _t("null"), "dump_state": _obj("DumpState", _SIM, {}, []),
        },
        "outputs": _outputs(),
        "language": ROBOT_LANGUAGE,
        "description": "Particularization for Duckiebot1 observations and commands with timestamps",
    }


def robot_protocol_description() -> dict:
    """The ``protocol_description`` data of a robot node (AIDO's ``protocol_simulator_DB20_timestamps``)."""
    return canonical({"data": _data_protocol(), "meta": _meta_protocol()})
