"""A stock AIDO simulator node, written with AIDO's own API the way AIDO's gym simulator node is.

``python stock_sim.py FRAME.jpg``: ``wrap_direct`` serves ``protocol_simulator_DB20_timestamps``; the
handlers mirror duckietown's ``challenge-aido_LF-simulator-gym`` (``gym_bridge``): the robot's
``RobotInterfaceDescription`` names the types only (no proxybench fields), robot state is
``DTSimRobotState`` with SE(2) / se(2) NumPy arrays, observations are written with their schema, the
episode ends with ``out-of-tile`` when the robot leaves the map. In place of gym-duckietown (OpenGL) the
robot is a unicycle (v = 0.6 m/s · mean PWM, ω = 0.6 m/s · (right − left) / 0.102 m) and the camera
sends the same JPEG every frame. It knows nothing of proxybench: ``yaml_payload`` keys it does not know
are ignored, as the gym simulator does.
"""

import logging
import math
import sys

import numpy as np
import yaml
from aido_schemas import (
    RGB,
    Context,
    DB20ObservationsWithTimestamp,
    DB20OdometryWithTimestamp,
    DB20RobotObservationsWithTimestamp,
    DB20SetRobotCommands,
    DTSimDuckieInfo,
    DTSimDuckieState,
    DTSimRobotInfo,
    DTSimRobotState,
    DTSimState,
    DTSimStateDump,
    EpisodeStart,
    GetDuckieState,
    GetRobotObservations,
    GetRobotState,
    JPGImage,
    JPGImageWithTimestamp,
    LEDSCommands,
    Metric,
    PerformanceMetrics,
    PWMCommands,
    RobotInterfaceDescription,
    RobotPerformance,
    SimulationState,
    SpawnDuckie,
    SpawnRobot,
    Step,
    Termination,
    wrap_direct,
)
from aido_schemas.schemas import DTSetMap, protocol_simulator_DB20_timestamps

logging.disable(logging.CRITICAL)

PHYSICS_DT = 1 / 200.0  # the gym simulator's minimum_physics_dt
ENCODER = 2 * math.pi / 135  # rad per odometry tick


def se2(x: float, y: float, theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


class StockSimulator:
    def __init__(self, jpg: bytes):
        self.jpg = jpg
        self.robots: dict = {}
        self.duckies: dict = {}

    def init(self, context: Context):
        pass

    def on_received_seed(self, context: Context, data: int):
        np.random.seed(data)

    def on_received_clear(self, context: Context):
        self.robots, self.duckies = {}, {}

    def on_received_set_map(self, context: Context, data: DTSetMap):
        m = yaml.safe_load(data.map_data)
        self.size = (len(m["tiles"][0]) * m["tile_size"], len(m["tiles"]) * m["tile_size"])

    def on_received_spawn_robot(self, context: Context, data: SpawnRobot):
        p = data.configuration.pose
        self.robots[data.robot_name] = {"pose": [p.x, p.y, math.radians(p.theta_deg)], "v": 0.0, "w": 0.0,
                                        "pwm": (0.0, 0.0), "axes": [0.0, 0.0], "playable": data.playable,
                                        "termination": None}

    def on_received_spawn_duckie(self, context: Context, data: SpawnDuckie):
        self.duckies[data.name] = se2(data.pose.x, data.pose.y, math.radians(data.pose.theta_deg))

    def on_received_get_robot_interface_description(self, context: Context, data: str):
        context.write("robot_interface_description",
                      RobotInterfaceDescription(robot_name=data, observations=JPGImage, commands=PWMCommands))

    def on_received_episode_start(self, context: Context, data: EpisodeStart):
        self.time = 0.0

    def on_received_set_robot_commands(self, context: Context, data: DB20SetRobotCommands):
        r = self.robots[data.robot_name]
        w = data.commands.wheels
        r["pwm"] = (0.0, 0.0) if r["termination"] else (w.motor_left, w.motor_right)

    def on_received_step(self, context: Context, data: Step):
        while self.time < data.until - 1e-9:
            dt = min(PHYSICS_DT, data.until - self.time)
            for r in self.robots.values():
                if not r["playable"]:
                    continue
                left, right = r["pwm"]
                r["v"], r["w"] = 0.6 * (left + right) / 2, 0.6 * (right - left) / 0.102
                x, y, th = r["pose"]
                r["pose"] = [x + r["v"] * math.cos(th) * dt, y + r["v"] * math.sin(th) * dt, th + r["w"] * dt]
                r["axes"] = [r["axes"][0] + 0.6 * left * dt / 0.0318, r["axes"][1] + 0.6 * right * dt / 0.0318]
            self.time += dt

    def _info(self, r) -> DTSimRobotInfo:
        c = RGB(0.0, 1.0, 0.0)
        v = np.array([[0.0, -r["w"], r["v"]], [r["w"], 0.0, 0.0], [0.0, 0.0, 0.0]])
        return DTSimRobotInfo(pose=se2(*r["pose"]), velocity=v, pwm=PWMCommands(*r["pwm"]),
                              leds=LEDSCommands(c, c, c, c, c))

    def on_received_get_robot_state(self, context: Context, data: GetRobotState):
        state = DTSimRobotState(data.robot_name, self.time, self._info(self.robots[data.robot_name]))
        context.write("robot_state", state)

    def on_received_get_robot_observations(self, context: Context, data: GetRobotObservations):
        r = self.robots[data.robot_name]
        ticks = [round(a / ENCODER) * ENCODER for a in r["axes"]]
        obs = DB20ObservationsWithTimestamp(
            JPGImageWithTimestamp(self.jpg, self.time),
            DB20OdometryWithTimestamp(resolution_rad=ENCODER, axis_left_rad=ticks[0], axis_right_rad=ticks[1],
                                      timestamp=self.time))
        context.write("robot_observations", DB20RobotObservationsWithTimestamp(data.robot_name, self.time, obs),
                      with_schema=True)

    def on_received_get_sim_state(self, context: Context):
        for name, r in self.robots.items():
            x, y, _ = r["pose"]
            if r["termination"] is None and not (0 <= x <= self.size[0] and 0 <= y <= self.size[1]):
                r["termination"] = Termination(when=self.time, desc=f"Robot {name!r} is out of tile.",
                                               code="out-of-tile")
        terms = {k: r["termination"] for k, r in self.robots.items()}
        done = any(t is not None for t in terms.values())
        context.write("sim_state", SimulationState(done=done, terminations=terms))

    def on_received_get_robot_performance(self, context: Context, data: str):
        metrics = {"survival_time": Metric(higher_is_better=True, cumulative_value=self.time,
                                           description="Survival time.")}
        context.write("robot_performance", RobotPerformance(data, self.time, PerformanceMetrics(metrics)))

    def on_received_get_duckie_state(self, context: Context, data: GetDuckieState):
        info = DTSimDuckieInfo(pose=self.duckies[data.duckie_name], velocity=np.zeros((3, 3)))
        context.write("duckie_state", DTSimDuckieState(data.duckie_name, self.time, info))

    def on_received_dump_state(self, context: Context):
        bots = {k: self._info(r) for k, r in self.robots.items()}
        duckies = {k: DTSimDuckieInfo(pose=p, velocity=np.zeros((3, 3))) for k, p in self.duckies.items()}
        context.write("state_dump", DTSimStateDump(DTSimState(self.time, bots, duckies)))

    def on_received_get_ui_image(self, context: Context):
        context.write("ui_image", JPGImage(self.jpg))


if __name__ == "__main__":
    with open(sys.argv[1], "rb") as f:
        frame = f.read()
    wrap_direct(node=StockSimulator(frame), protocol=protocol_simulator_DB20_timestamps, args=[])
