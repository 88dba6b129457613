"""SDK agents that misbehave, one per argument: silent, crash, flood, nan."""
import sys
import time

from duckietown.sdk.robots.duckiebot import DB21J

how = sys.argv[1]
robot = DB21J("map_0/vehicle_0", simulated=True)
robot.camera.start()
robot.motors.start()
frames = 0
while True:
    if robot.camera.capture(block=True) is None:
        continue
    frames += 1
    if how == "silent":
        continue
    if how == "crash" and frames == 3:
        print("giving up on frame 3", file=sys.stderr)
        sys.exit(3)
    if how == "nan":  # the SDK refuses NaN in set_pwm; a hand-made message still reaches the robot
        robot.motors._override_msg = {"left": float("nan"), "right": 0.0}
    robot.motors.set_pwm(0.2, 0.2)
    if how == "flood":  # four publishers, each as fast as the robot acknowledges
        others = [DB21J("map_0/vehicle_0", simulated=True) for _ in range(3)]
        for other in others:
            other.motors.start()
        end = time.monotonic() + 5.0
        while time.monotonic() < end:
            for r in (robot, *others):
                r.motors.set_pwm(0.2, 0.2)
            time.sleep(0.0001)
