"""A lane-following agent written against duckietown-sdk's public API only (as its README shows it).

Finds the yellow centre line and the white edge in the lower half of the BGR camera frame and steers
between them. Runs unchanged on the Duckiematrix, a real DB21J (``DB21J("mybot")``) or proxybench.
"""
import numpy as np
from duckietown.sdk.robots.duckiebot import DB21J

robot = DB21J("map_0/vehicle_0", simulated=True)
robot.camera.start()
robot.motors.start()
while True:
    bgr = robot.camera.capture(block=True)
    if bgr is None:
        continue
    h, w = bgr.shape[:2]
    low = bgr[h // 2:].astype(np.int16)
    yellow = (low[..., 2] > 150) & (low[..., 1] > 120) & (low[..., 0] < 100)
    white = low.min(axis=2) > 170
    xs_y, xs_w = np.nonzero(yellow)[1], np.nonzero(white)[1]
    centre = w / 2
    if xs_y.size and xs_w.size:
        centre = (xs_y.mean() + xs_w.mean()) / 2
    elif xs_y.size:
        centre = xs_y.mean() + 0.3 * w
    elif xs_w.size:
        centre = xs_w.mean() - 0.3 * w
    err = (centre - w / 2) / (w / 2)
    robot.motors.set_pwm(0.25 + 0.15 * err, 0.25 - 0.15 * err)
