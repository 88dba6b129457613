"""A linear-quadratic regulator for lane keeping, privileged: state feedback designed, not tuned by hand.

The lane-relative unicycle (offset e [m], + = left; heading error ψ [rad], + = left) at cruise speed v is,
linearised about the lane centre and sampled at the agent's frame period dt with the turn rate held between
frames (a zero-order hold, as the runner holds commands):

    e' = e + v dt ψ + ½ v dt² u,   ψ' = ψ + dt u,      u = ω − v κ  (the turn rate beyond the lane's own)

The gain K minimises Σ xᵀQx + uᵀRu (the discrete algebraic Riccati equation, :func:`scipy.linalg.solve_discrete_are`)
and the command is ω = v κ − K x. With ``delay_frames`` = 1 the design also carries the command issued one
frame earlier as a state (a command that takes effect a frame late, as the robot's command delay does), so the
regulator anticipates it. The PWM comes from the nominal DB18 model, as for the other privileged agents.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import solve_discrete_are

from proxybench.agents.base import Agent, Observation
from proxybench.agents.pid import wheels_for

__all__ = ["LQRAgent", "lqr_gain"]


def lqr_gain(speed: float, dt: float, q_lateral: float, q_heading: float, r: float,
             delay_frames: int = 0) -> np.ndarray:
    """The state-feedback gain K (row vector) of the sampled lane-keeping model; see the module docstring.

    ``q_lateral`` [1/m²], ``q_heading`` [1/rad²] and ``r`` [s²/rad²] weigh offset, heading error and turn rate;
    with ``delay_frames`` = 1 the state is (e, ψ, u_prev) and K has three entries.
    """
    if speed <= 0 or dt <= 0 or q_lateral <= 0 or q_heading <= 0 or r <= 0:
        raise ValueError(f"need speed, dt, q_lateral, q_heading, r > 0; got {speed}, {dt}, {q_lateral}, "
                         f"{q_heading}, {r}")
    if delay_frames not in (0, 1):
        raise ValueError(f"delay_frames must be 0 or 1, got {delay_frames}")
    a = np.array([[1.0, speed * dt], [0.0, 1.0]])
    b = np.array([[0.5 * speed * dt * dt], [dt]])
    q = np.diag([q_lateral, q_heading])
    if delay_frames:
        a = np.block([[a, b], [np.zeros((1, 3))]])
        b = np.array([[0.0], [0.0], [1.0]])
        q = np.diag([q_lateral, q_heading, 0.0])
    rr = np.array([[r]])
    p = solve_discrete_are(a, b, q, rr)
    return np.linalg.solve(rr + b.T @ p @ b, b.T @ p @ a)[0]


class LQRAgent(Agent):
    """ω = v κ − K x on the true lane pose at ``speed`` [m/s]; weights as in :func:`lqr_gain` (Bryson's rule:
    q = 1 / acceptable², so the defaults accept 3 cm of offset, 0.3 rad of heading error, 2 rad/s of turn)."""

    privileged = True
    name = "lqr"

    def __init__(self, speed: float = 0.3, max_lateral: float = 0.03, max_heading: float = 0.3, max_turn: float = 2.0,
                 delay_frames: int = 0, frame_dt: float = 1 / 15):
        self.speed, self.frame_dt, self.delay_frames = speed, frame_dt, delay_frames
        self.gain = lqr_gain(speed, frame_dt, 1.0 / max_lateral**2, 1.0 / max_heading**2, 1.0 / max_turn**2,
                             delay_frames)
        self._u_prev = 0.0

    def reset(self, seed: int, episode: str | None = None) -> None:
        self._u_prev = 0.0

    def act(self, obs: Observation) -> np.ndarray:
        lp = self.true_lane_pose(obs)
        if not lp.valid:
            self._u_prev = 0.0
            return np.zeros(2)
        x = [lp.lateral, lp.heading_error] + ([self._u_prev] if self.delay_frames else [])
        u = float(np.clip(-self.gain @ np.asarray(x), -8.0, 8.0))
        self._u_prev = u
        return wheels_for(self.speed, self.speed * lp.curvature + u)
