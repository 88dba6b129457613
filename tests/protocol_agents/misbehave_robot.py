"""A minimal robot node (cbor2 only, so it starts fast) that misbehaves on purpose.

``python misbehave_robot.py MODE [TRIGGER]``: answers the robot protocol with a fixed, valid robot (no
camera, no proxybench trace) until the first input whose topic (or control code) is TRIGGER (default
``step``), then does MODE instead of answering. MODEs are those of ``misbehave.py`` plus ``bad-data``
(observations without a camera), ``bad-lane-pose`` (a malformed proxybench lane pose), ``no-understood``
(an answer that skips it), ``wrong-robot`` (an answer about another robot) and ``nan-state`` (a state
with a non-number in its pose). Its state is a robot standing still, with a clock that ``step`` moves.
"""

import math
import sys

import cbor2
import misbehave as mb

DESCRIPTION = {"data": {"inputs": {t: {} for t in ("seed", "clear", "set_map", "spawn_robot", "episode_start", "step",
                                                   "set_robot_commands", "get_robot_observations", "get_robot_state",
                                                   "get_sim_state", "get_robot_interface_description")},
                        "outputs": {t: {} for t in ("robot_observations", "robot_state", "sim_state",
                                                    "robot_interface_description")},
                        "language": "", "description": "misbehaving robot"},
               "meta": {}}
INFO = {"robot_name": "ego", "observations": {}, "commands": {}, "proxybench": {"kind": "robot", "frame_rate": 15.0}}
ODOMETRY = {"resolution_rad": 0.05, "axis_left_rad": 0.0, "axis_right_rad": 0.0, "timestamp": 0.0}
OBSERVATIONS = {"robot_name": "ego", "t_effective": 0.0,
                "observations": {"camera": {"jpg_data": b"", "timestamp": 0.0}, "odometry": ODOMETRY}}
STATE = {"robot_name": "ego", "t_effective": 0.0,
         "state": {"pose": {"x": 0.3, "y": 0.3, "theta_deg": 0.0}, "velocity": {"x": 0.0, "y": 0.0, "theta_deg": 0.0},
                   "pwm": {"motor_left": 0.0, "motor_right": 0.0}, "leds": {}}}


NOW = [0.0]  # the robot's clock [s], advanced by step


def outputs(topic, data=None):
    if topic == "step":
        NOW[0] = max(NOW[0], data["until"])
    elif topic == "clear":
        NOW[0] = 0.0
    if topic == "wrapper.describe_protocol":
        return [mb.topic("protocol_description", DESCRIPTION)]
    if topic == "get_robot_interface_description":
        return [mb.topic("robot_interface_description", INFO)]
    if topic == "get_robot_observations":
        return [mb.topic("robot_observations", OBSERVATIONS)]
    if topic == "get_robot_state":
        return [mb.topic("robot_state", {**STATE, "t_effective": NOW[0]})]
    if topic == "get_sim_state":
        return [mb.topic("sim_state", {"done": False, "terminations": {"ego": None}})]
    return []


def misbehave(mode, topic):
    if mode == "bad-data":
        broken = {**OBSERVATIONS, "observations": {"odometry": ODOMETRY}}
        mb.send(mb.ctrl("understood"), mb.topic("robot_observations", broken), mb.ctrl("over"))
    elif mode == "wrong-robot":
        mb.send(mb.ctrl("understood"), *[mb.topic(o["topic"], {**o["data"], "robot_name": "other"})
                                         for o in outputs(topic)], mb.ctrl("over"))
    elif mode == "bad-lane-pose":
        obs = {**OBSERVATIONS["observations"], "proxybench": {"lane_pose": {"valid": True}}}
        mb.send(mb.ctrl("understood"), mb.topic("robot_observations", {**OBSERVATIONS, "observations": obs}),
                mb.ctrl("over"))
    elif mode == "no-understood":
        mb.send(mb.topic("robot_state", STATE), mb.ctrl("over"))
    elif mode == "nan-state":
        nan = {**STATE, "state": {**STATE["state"], "pose": {"x": math.nan, "y": "far", "theta_deg": 0.0}}}
        mb.send(mb.ctrl("understood"), mb.topic("robot_state", nan), mb.ctrl("over"))
    else:
        mb.misbehave(mode)
    mb.hang()


def main():
    mb.IN, mb.OUT = mb._streams()
    mode = sys.argv[1]
    trigger = sys.argv[2] if len(sys.argv) > 2 else "step"
    decoder = cbor2.CBORDecoder(mb.IN)
    while True:
        try:
            msg = decoder.decode()
        except (cbor2.CBORDecodeEOF, EOFError):
            return
        key = msg.get("control", msg.get("topic"))
        if key == trigger:
            misbehave(mode, key)
        if "control" in msg:
            mb.answer(msg)
        else:
            mb.send(mb.ctrl("understood"), *outputs(key, msg.get("data")), mb.ctrl("over"))


if __name__ == "__main__":
    main()
