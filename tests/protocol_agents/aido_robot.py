"""A stand-in for a stock AIDO simulator node (cbor2 and NumPy only, so it starts fast).

Its messages are shaped as AIDO's gym simulator writes them (``tests/aido/stock_sim.py`` is the same robot
written with AIDO's own API): ``robot_interface_description`` without proxybench fields, ``robot_state``
with SE(2) / se(2) NumPy arrays as zuper encodes them, observations carrying their ``$schema``,
``out-of-tile`` when the robot leaves the map. Like zuper nodes on Python >= 3.11 it aborts on
``describe_protocol`` and exits. The robot is a unicycle (v = 0.6 m/s · mean PWM, ω = 0.6 · (right −
left) / 0.102 rad/s) integrated at 200 Hz; the camera sends the JPEG file given as argument.
"""

import math
import sys

import cbor2
import misbehave as mb
import numpy as np
import yaml
from misbehave import ctrl, send, topic  # send writes to mb.OUT, set in main()


def arr(a):
    a = np.ascontiguousarray(a, dtype="<f8")
    return {"data": a.tobytes(), "dtype": "float64", "shape": list(a.shape)}


def se2(x, y, th):
    return np.array([[math.cos(th), -math.sin(th), x], [math.sin(th), math.cos(th), y], [0, 0, 1.0]])


def main():
    with open(sys.argv[1], "rb") as f:
        jpg = f.read()
    mb.IN, mb.OUT = mb._streams()
    decoder = cbor2.CBORDecoder(mb.IN)
    robot, size, now, term = {}, (1.0, 1.0), 0.0, None
    while True:
        try:
            msg = decoder.decode()
        except (cbor2.CBORDecodeEOF, EOFError):
            return 0
        if "control" in msg:
            send(ctrl("understood"), ctrl("capabilities", {"z2": {"protocol-reflection": True}}), ctrl("over"))
            continue
        t, data, out = msg["topic"], msg["data"], []
        if t == "wrapper.describe_protocol":
            send(ctrl("understood"), ctrl("aborted", "ZValueError: Cannot interpret the type @T\n| T: typing.Any"),
                 ctrl("over"))
            return 1
        if t == "set_map":
            m = yaml.safe_load(data["map_data"])
            size = (len(m["tiles"][0]) * m["tile_size"], len(m["tiles"]) * m["tile_size"])
        elif t == "spawn_robot":
            p = data["configuration"]["pose"]
            robot = {"pose": [p["x"], p["y"], math.radians(p["theta_deg"])], "pwm": (0.0, 0.0), "v": 0.0, "w": 0.0}
        elif t == "episode_start":
            now, term = 0.0, None
        elif t == "set_robot_commands":
            w = data["commands"]["wheels"]
            robot["pwm"] = (0.0, 0.0) if term else (w["motor_left"], w["motor_right"])
        elif t == "step":
            while now < data["until"] - 1e-9:
                dt = min(0.005, data["until"] - now)
                left, right = robot["pwm"]
                robot["v"], robot["w"] = 0.6 * (left + right) / 2, 0.6 * (right - left) / 0.102
                x, y, th = robot["pose"]
                robot["pose"] = [x + robot["v"] * math.cos(th) * dt, y + robot["v"] * math.sin(th) * dt,
                                 th + robot["w"] * dt]
                now += dt
        elif t == "get_robot_interface_description":
            out = [topic("robot_interface_description", {"robot_name": data, "observations": {"title": "JPGImage"},
                                                         "commands": {"title": "PWMCommands"}})]
        elif t == "get_robot_state":
            twist = [[0, -robot["w"], robot["v"]], [robot["w"], 0, 0], [0, 0, 0]]
            state = {"pose": arr(se2(*robot["pose"])), "velocity": arr(twist), "leds": {},
                     "pwm": {"motor_left": float(robot["pwm"][0]), "motor_right": float(robot["pwm"][1])}}
            out = [topic("robot_state", {"robot_name": data["robot_name"], "t_effective": now, "state": state})]
        elif t == "get_robot_observations":
            obs = {"camera": {"jpg_data": jpg, "timestamp": now, "$schema": {"title": "JPGImageWithTimestamp"}},
                   "odometry": {"resolution_rad": 0.05, "axis_left_rad": 0.0, "axis_right_rad": 0.0,
                                "timestamp": now}}
            out = [topic("robot_observations", {"robot_name": data["robot_name"], "t_effective": now,
                                                "observations": obs, "$schema": {"title": "DB20RobotObservations"}})]
        elif t == "get_sim_state":
            x, y, _ = robot["pose"]
            if term is None and not (0 <= x <= size[0] and 0 <= y <= size[1]):
                term = {"when": now, "desc": "Robot 'ego' is out of tile.", "code": "out-of-tile"}
            out = [topic("sim_state", {"done": term is not None, "terminations": {"ego": term}})]
        send(ctrl("understood"), *out, ctrl("over"))


if __name__ == "__main__":
    sys.exit(main())
