"""The privileged expert (pure pursuit on the true lane pose), vectorised over a batch of robots.

Behaviour cloning needs the expert's action for every robot of a batched ``Simulator`` every frame.
Calling ``PurePursuitAgent.act`` once per robot would put a Python loop (and a ``LanePose`` object) in
the hot path, so this module computes the same control law on the simulator's lane-pose array in one
NumPy expression. It is tested to agree with ``PurePursuitAgent`` to machine precision.

>>> import numpy as np
>>> from proxybench.domain.lane_pose import LP
>>> lane = np.zeros((1, LP.N)); lane[0, LP.VALID] = 1.0
>>> expert_actions(lane).round(3)   # on the lane centre, on a straight: both wheels alike
array([[0.583, 0.583]])
"""

from __future__ import annotations

import numpy as np

from proxybench.domain.lane_pose import LP

__all__ = ["EXPERT_LOOKAHEAD", "EXPERT_SPEED", "expert_actions", "expert_vw", "vw_to_wheels", "wheels_to_vw"]

#: the zoo's "pure-pursuit" agent: 0.35 m/s with a 0.25 m lookahead
EXPERT_SPEED = 0.35
EXPERT_LOOKAHEAD = 0.25
# nominal DB18 steady state (the constants ``agents.pid.wheels_for`` inverts)
_A_V, _B_V, _A_W, _B_W = 5.0, 1.5, 4.0, 15.0


def expert_vw(lane: np.ndarray, speed: float = EXPERT_SPEED, lookahead: float = EXPERT_LOOKAHEAD) -> np.ndarray:
    """(N, 2) demanded (v [m/s], ω [rad/s]) of pure pursuit for lane-pose rows (N, LP.N); (0, 0) where invalid."""
    lat, herr, kappa = lane[:, LP.LATERAL], lane[:, LP.HEADING_ERROR], lane[:, LP.CURVATURE]
    valid = (lane[:, LP.VALID] > 0.5) & np.isfinite(lat) & np.isfinite(herr)
    lat, herr = np.where(valid, lat, 0.0), np.where(valid, herr, 0.0)
    straight = np.abs(kappa) < 1e-9
    k = np.where(straight, 1.0, kappa)
    tx = np.where(straight, lookahead, np.sin(k * lookahead) / k)
    ty = np.where(straight, 0.0, (1.0 - np.cos(k * lookahead)) / k)
    dx, dy = tx, ty - lat
    c, s = np.cos(herr), np.sin(herr)
    x, y = c * dx + s * dy, -s * dx + c * dy
    omega = speed * 2.0 * y / np.maximum(x * x + y * y, 1e-6)
    return np.where(valid[:, None], np.stack([np.full_like(omega, speed), omega], axis=1), 0.0)


def vw_to_wheels(vw: np.ndarray) -> np.ndarray:
    """PWM (left, right) whose nominal steady state is (v, ω); the vectorised ``agents.pid.wheels_for``."""
    vw = np.asarray(vw, dtype=np.float64)
    total = vw[..., 0] * _A_V / _B_V
    diff = vw[..., 1] * _A_W / _B_W
    return np.clip(np.stack([0.5 * (total - diff), 0.5 * (total + diff)], axis=-1), -1.0, 1.0)


def wheels_to_vw(pwm: np.ndarray) -> np.ndarray:
    """The inverse of :func:`vw_to_wheels` (exact where the PWM was not clipped)."""
    pwm = np.asarray(pwm, dtype=np.float64)
    total, diff = pwm[..., 0] + pwm[..., 1], pwm[..., 1] - pwm[..., 0]
    return np.stack([total * _B_V / _A_V, diff * _B_W / _A_W], axis=-1)


def expert_actions(lane: np.ndarray, speed: float = EXPERT_SPEED, lookahead: float = EXPERT_LOOKAHEAD) -> np.ndarray:
    """(N, 2) wheel PWM of the pure-pursuit expert for lane-pose rows (N, LP.N); zeros where invalid."""
    vw = expert_vw(lane, speed, lookahead)
    valid = np.any(vw != 0.0, axis=1)
    return np.where(valid[:, None], vw_to_wheels(vw), 0.0)
