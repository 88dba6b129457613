"""Scripted open-loop drives for calibrating a robot without a simulator (the validation study's ``calibration``
method, :mod:`proxybench.usefulness.calibration`): a straight drive at constant PWM (trim from yaw rate over
speed) and a step drive (wheels still, then a step in the command: the command delay from when the pose starts
to move). They read only the episode clock, so they run on any target, a robot included.
"""

from __future__ import annotations

import numpy as np

from proxybench.agents.base import Agent, Observation

__all__ = ["CALIBRATION_DRIVES", "STEP_TIME", "STRAIGHT_PWM", "StepDriveAgent", "StraightDriveAgent"]

#: the PWM of both drives (both wheels alike): slow enough to stay in the lane a while
STRAIGHT_PWM = 0.4
#: when the step drive's command steps from 0 to :data:`STRAIGHT_PWM` [s after the episode start]
STEP_TIME = 1.0


class StraightDriveAgent(Agent):
    """The same PWM on both wheels from the first frame: a robot with no trim drives straight."""

    name = "calib-straight"

    def __init__(self, pwm: float = STRAIGHT_PWM):
        if not 0.0 < pwm <= 1.0:
            raise ValueError(f"pwm must be in (0, 1], got {pwm}")
        self.pwm = pwm

    def act(self, obs: Observation) -> np.ndarray:
        return np.array([self.pwm, self.pwm])


class StepDriveAgent(Agent):
    """Wheels still until ``step_time`` [s], then the same PWM on both: the pose's lag behind the step is the
    command delay (plus the motors' response, which the estimator models)."""

    name = "calib-step"

    def __init__(self, pwm: float = STRAIGHT_PWM, step_time: float = STEP_TIME):
        if not 0.0 < pwm <= 1.0 or step_time < 0:
            raise ValueError(f"need 0 < pwm <= 1 and step_time >= 0, got pwm={pwm}, step_time={step_time}")
        self.pwm, self.step_time = pwm, step_time

    def act(self, obs: Observation) -> np.ndarray:
        on = obs.time >= self.step_time - 1e-6  # frame times are multiples of the frame period, up to rounding
        return np.array([self.pwm, self.pwm]) if on else np.zeros(2)


#: (zoo name, factory, description) of each drive, for the zoo
CALIBRATION_DRIVES = (
    ("calib-straight", StraightDriveAgent, f"calibration drive: PWM {STRAIGHT_PWM} on both wheels from the start"),
    ("calib-step", StepDriveAgent, f"calibration drive: still for {STEP_TIME:g} s, then PWM {STRAIGHT_PWM} on both"),
)
