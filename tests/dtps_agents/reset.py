"""Drives straight on every camera frame and asks the robot for a reset (state/reset) every second.

It reads the camera as any driving agent does. That matters: duckietown-sdk 0.2.0 hands a command to its
publisher through an asyncio queue filled from the user's thread without waking the SDK's event loop, so
commands and reset flags leave only when a packet (a camera frame) wakes that loop. A program that
subscribes to nothing never sends anything (docs/dtps.md, "An SDK quirk").
"""
import time

from duckietown.sdk.robots.duckiebot import DB21J

robot = DB21J("map_0/vehicle_0", simulated=True)
robot.camera.start()
robot.motors.start()
robot.reset_flag.start()
start = time.monotonic()
while True:
    if robot.camera.capture(block=True) is None:
        continue
    robot.motors.set_pwm(0.2, 0.2)
    if time.monotonic() - start > 1.0:
        robot.reset_flag.set_reset(True)
        start = time.monotonic()
