"""The node's answer to ``wrapper.describe_protocol``: the agent and meta protocols as JSON schemas.

Built to equal, key order included, what the recorded zuper-nodes agent node answers (the tests compare
it with the capture), so a caller that inspects node descriptions cannot tell a served proxybench agent
from an AIDO one. The one deliberate difference is opt-in: a *privileged* agent's description declares
the proxybench extension, an optional ``proxybench`` field of ``observations`` (see docs/protocol.md).
"""

from __future__ import annotations

import dataclasses
from typing import Any

from proxybench.domain.lane_pose import LanePose
from proxybench.protocol.language import AGENT_LANGUAGE, META_LANGUAGE
from proxybench.protocol.wire import canonical

__all__ = ["EXTENSION_KEY", "declares_extension", "decode_extras", "encode_extras", "protocol_description"]

EXTENSION_KEY = "proxybench"
_S = "http://json-schema.org/draft-07/schema#"
_META_MODULE = "zuper_nodes_wrapper.meta_protocol"


def _t(kind: str) -> dict:
    return {"type": kind, "$schema": _S}


def _float() -> dict:
    return {"type": "number", "title": "float", "$schema": _S}


def _any() -> dict:
    return {"title": "Any", "$schema": _S}


def _obj(name: str, module: str, props: dict, order: list[str], description: str | None = None,
         required: bool = True) -> dict:
    """A dataclass schema as zuper writes it (``required`` sorted, ``order`` as declared)."""
    d: dict[str, Any] = {"$id": f"http://invalid.json-schema.org/{name}#", "type": "object", "order": order,
                         "title": name, "$schema": _S, "__module__": module, "__qualname__": name}
    if props:
        d["properties"] = props
        if required:
            d["required"] = sorted(order)
    if description is not None:
        d["description"] = description
    return d


def _rgb() -> dict:
    return _obj("RGB", "aido_schemas.schemas", {c: _float() for c in "rgb"}, ["r", "g", "b"],
                "Values between 0, 1.")


def _commands() -> dict:
    leds_order = ["center", "front_left", "front_right", "back_left", "back_right"]
    leds = _obj("LEDSCommands", "aido_schemas.schemas", {k: _rgb() for k in leds_order}, leds_order)
    wheels = _obj("PWMCommands", "aido_schemas.schemas", {"motor_left": _float(), "motor_right": _float()},
                  ["motor_left", "motor_right"], "\n    PWM commands are floats between -1 and 1.\n    ")
    return _obj("DB20Commands", "aido_schemas.schemas", {"LEDS": leds, "wheels": wheels}, ["wheels", "LEDS"])


def _observations(privileged: bool) -> dict:
    jpg = _obj("JPGImageWithTimestamp", "aido_schemas.protocol_simulator",
               {"jpg_data": {"type": "string", "title": "bytes", "$schema": _S}, "timestamp": _float()},
               ["jpg_data", "timestamp"])
    odo_order = ["resolution_rad", "axis_left_rad", "axis_right_rad", "timestamp"]
    odo = _obj("DB20OdometryWithTimestamp", "aido_schemas.schemas", {k: _float() for k in odo_order}, odo_order)
    obs = _obj("DB20ObservationsWithTimestamp", "aido_schemas.schemas", {"camera": jpg, "odometry": odo},
               ["camera", "odometry"])
    if privileged:  # optional: not in "order" nor "required", so the AIDO type is unchanged
        obs["properties"][EXTENSION_KEY] = _extension_schema()
    return obs


_FIELD_SCHEMAS = {"bool": lambda: _t("boolean"), "int": lambda: _t("integer"), "float": _float,
                  "tuple[int, int]": lambda: {"type": "array", "items": _t("integer"), "$schema": _S}}


def _extension_schema() -> dict:
    """``{"lane_pose": LanePose | null}``, the fields generated from the LanePose dataclass."""
    fields = dataclasses.fields(LanePose)
    lane = _obj("LanePose", "proxybench.domain.lane_pose", {f.name: _FIELD_SCHEMAS[str(f.type)]() for f in fields},
                [f.name for f in fields], "True lane-relative pose of the robot (privileged).")
    lane = {"anyOf": [lane, _t("null")], "$schema": _S}
    return _obj("ProxybenchExtras", "proxybench.protocol", {"lane_pose": lane}, ["lane_pose"],
                "proxybench extension, sent only to nodes that declare it: ground truth for privileged agents.")


def _episode_start() -> dict:
    episode = _obj("EpisodeStart", "aido_schemas.protocol_agent",
                   {"episode_name": _t("string"),
                    "yaml_payload": {"anyOf": [_t("string")], "$schema": _S, "default": "{}"}},
                   ["episode_name", "yaml_payload"], "Marker for the start of an episode.")
    episode["required"] = ["episode_name"]
    return episode


def _data_protocol(privileged: bool) -> dict:
    episode = _episode_start()
    get_commands = _obj("GetCommands", "aido_schemas.protocol_agent", {"at_time": _float()}, ["at_time"])
    return {
        "inputs": {"seed": _t("integer"), "get_commands": get_commands, "observations": _observations(privileged),
                   "episode_start": episode},
        "outputs": {"commands": _commands()},
        "language": AGENT_LANGUAGE,
        "description": "Particularization for DB20 observations and commands and timestamps.",
    }


def _interaction_protocol() -> dict:
    typ = {"$ref": _S, "title": "type"}
    dict_of_types = {"type": "object", "title": "Dict[str,type]", "$schema": _S, "properties": {"$schema": {}},
                     "additionalProperties": typ}
    return _obj("InteractionProtocol", "zuper_nodes.language",
                {"inputs": dict_of_types, "outputs": dict(dict_of_types), "language": _t("string"),
                 "description": _t("string")}, ["description", "inputs", "outputs", "language"],
                "InteractionProtocol(description: str, inputs: Dict[str, type], outputs: Dict[str, type], "
                "language: str)")


def _meta_outputs() -> dict:
    def described(name: str, props: dict, order: list[str], signature: str) -> dict:
        return _obj(name, _META_MODULE, props, order, f"{name}({signature})")

    return {
        "logs": {"type": "array", "items": _t("string"), "title": "List[str]", "$schema": _S},
        "aborted": _t("string"), "node_state": _any(), "set_state_ack": _t("null"), "set_config_ack": _t("null"),
        "set_state_error": _t("string"),
        "node_description": described("NodeDescription", {"description": _t("string")}, ["description"],
                                      "description: str"),
        "set_config_error": _t("string"),
        "build_description": described("BuildDescription", {}, [], ""),
        "config_description": described("ConfigDescription", {"config": {"$ref": _S, "title": "type"},
                                                              "current": _any()},
                                        ["config", "current"], "config: type, current: Any"),
        "protocol_description": described(
            "ProtocolDescription", {"data": _interaction_protocol(), "meta": _interaction_protocol()},
            ["data", "meta"],
            "data: zuper_nodes.language.InteractionProtocol, meta: zuper_nodes.language.InteractionProtocol"),
    }


def _meta_protocol() -> dict:
    set_config = _obj("SetConfig", _META_MODULE, {"key": _t("string"), "value": _any()}, ["key", "value"],
                      "SetConfig(key: str, value: Any)")
    inputs = {name: _t("null") for name in ("get_logs", "get_state", "describe_node", "describe_build",
                                             "describe_config", "describe_protocol")}
    inputs.update(set_state=_any(), set_config=set_config)
    return {"inputs": inputs, "outputs": _meta_outputs(), "language": META_LANGUAGE,
            "description": "\nBasic interaction protocol for nodes spoken by the node wrapper.\n\n    "}


def protocol_description(privileged: bool = False) -> dict:
    """The ``protocol_description`` data; with ``privileged``, declaring the proxybench extension."""
    return canonical({"data": _data_protocol(privileged), "meta": _meta_protocol()})


def declares_extension(description: Any) -> bool:
    """Whether a node's protocol description declares the optional ``observations.proxybench`` field."""
    try:
        props = description["data"]["inputs"]["observations"]["properties"]
    except (KeyError, TypeError):
        return False
    return isinstance(props, dict) and EXTENSION_KEY in props


_CONVERT = {"bool": bool, "int": int, "float": float, "tuple[int, int]": lambda v: (int(v[0]), int(v[1]))}


def encode_extras(lane_pose: LanePose | None) -> dict:
    """The ``observations.proxybench`` value: ``{"lane_pose": {field: value} | None}``, floats as floats."""
    if lane_pose is None:
        return {"lane_pose": None}
    row = {}
    for f in dataclasses.fields(LanePose):
        value = _CONVERT[str(f.type)](getattr(lane_pose, f.name))
        row[f.name] = list(value) if isinstance(value, tuple) else value
    return {"lane_pose": row}


def decode_extras(extras: dict | None) -> LanePose | None:
    """The lane pose carried by an ``observations.proxybench`` value (None when absent)."""
    row = (extras or {}).get("lane_pose")
    if row is None:
        return None
    if not isinstance(row, dict):
        raise TypeError("observations.proxybench.lane_pose must be a map or null")
    try:
        return LanePose(**{f.name: _CONVERT[str(f.type)](row[f.name]) for f in dataclasses.fields(LanePose)})
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise TypeError(f"observations.proxybench.lane_pose is malformed: {exc!r}") from exc
