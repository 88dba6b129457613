"""Drives straight and asks the robot for a reset after one second (state/reset), again and again."""
import time

from duckietown.sdk.robots.duckiebot import DB21J

robot = DB21J("map_0/vehicle_0", simulated=True)
robot.motors.start()
robot.reset_flag.start()
while True:
    start = time.monotonic()
    while time.monotonic() - start < 1.0:
        robot.motors.set_pwm(0.2, 0.2)
        time.sleep(0.05)
    robot.reset_flag.set_reset(True)
