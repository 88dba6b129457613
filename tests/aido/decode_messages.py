"""Decode robot-protocol messages with AIDO's own types, as AIDO's experiment manager does.

``python decode_messages.py MESSAGES.cbor``: the file holds CBOR topic messages back to back (what a caller
sent and what a robot node answered); each message's ``data`` is decoded by zuper-ipce's
``object_from_ipce`` into the type that ``aido_schemas.protocol_simulator_DB20_timestamps`` declares for
its topic (inputs and outputs alike), then checked with the type's own validation (e.g. PWM in [-1, 1]).
Prints one JSON line per message: ``{"topic", "ok", "error"?, "value"?}``, with a few decoded values
(poses as matrices) so that the test can compare them with what proxybench meant.
"""

import json
import logging
import sys

logging.disable(logging.CRITICAL)

import cbor2  # noqa: E402
import numpy as np  # noqa: E402
from aido_schemas.schemas import protocol_simulator_DB20_timestamps as PROTOCOL  # noqa: E402
from zuper_ipce import IEDO, object_from_ipce  # noqa: E402

IEDO_ = IEDO(True, True)


def summary(topic: str, obj) -> object:
    """A few decoded values, JSON-able."""
    if topic == "robot_state":
        return {"robot_name": obj.robot_name, "t_effective": obj.t_effective,
                "pose": np.asarray(obj.state.pose).tolist(), "velocity": np.asarray(obj.state.velocity).tolist(),
                "pwm": [obj.state.pwm.motor_left, obj.state.pwm.motor_right]}
    if topic == "duckie_state":
        return {"duckie_name": obj.duckie_name, "pose": np.asarray(obj.state.pose).tolist()}
    if topic == "state_dump":
        return {"t_effective": obj.state.t_effective, "duckiebots": sorted(obj.state.duckiebots),
                "duckies": sorted(obj.state.duckies)}
    if topic == "spawn_robot":
        return {"robot_name": obj.robot_name, "x": obj.configuration.pose.x, "y": obj.configuration.pose.y,
                "theta_deg": obj.configuration.pose.theta_deg, "dynamics": obj.dynamics}
    if topic == "sim_state":
        return {"done": obj.done, "terminations": {k: None if v is None else v.code
                                                   for k, v in obj.terminations.items()}}
    if topic == "robot_observations":
        return {"t_effective": obj.t_effective, "jpg_bytes": len(obj.observations.camera.jpg_data),
                "timestamp": obj.observations.camera.timestamp}
    if topic in ("ui_image",):
        return {"jpg_bytes": len(obj.jpg_data)}
    return None


def main(path: str) -> None:
    with open(path, "rb") as f:
        data = f.read()
    decoder_stream = cbor2.CBORDecoder(__import__("io").BytesIO(data))
    while decoder_stream.fp.tell() < len(data):
        msg = decoder_stream.decode()
        if "topic" not in msg:
            continue
        topic = msg["topic"]
        kind = PROTOCOL.outputs.get(topic) or PROTOCOL.inputs.get(topic)
        row = {"topic": topic}
        if kind is None:
            row.update(ok=False, error=f"no such topic in {PROTOCOL.description!r}")
        else:
            try:
                obj = object_from_ipce(msg["data"], kind, iedo=IEDO_)
                row.update(ok=True, value=summary(topic, obj), type=getattr(kind, "__name__", str(kind)))
            except Exception as exc:  # what a failed decode says is the test's evidence
                row.update(ok=False, error=f"{type(exc).__name__}: {exc}"[:2000])
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main(sys.argv[1])
