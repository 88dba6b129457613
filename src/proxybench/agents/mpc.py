"""A sampling model-predictive controller, privileged: try a fan of constant arcs, keep the cheapest, repeat.

Every frame the agent rolls each candidate (turn rate ω, speed v) forward for ``horizon`` seconds in the
lane-relative unicycle model — offset e [m] (+ = left), heading error ψ [rad], the lane ahead taken as an arc of
the curvature κ under the robot:

    ė = v sin ψ,   ψ̇ = ω − v κ cos ψ / (1 − κ e)

and scores the rollout by Σ (e²/e₀² + ψ²/ψ₀²) dt, a penalty for leaving the lane (|e| > 0.1 m), a cost on
changing the turn rate from the last frame's, and a reward for progress along the lane. It applies the cheapest
candidate's first command (receding horizon). No gains are tuned: the behaviour comes from the horizon, the
candidate set and the cost's weights. The PWM comes from the nominal DB18 model, as for the other privileged agents.
"""

from __future__ import annotations

import math

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.agents.pid import wheels_for

__all__ = ["ArcSamplerAgent", "rollout_costs"]

_LANE_EDGE = 0.1  # [m] offset beyond which a wheel leaves the lane


def rollout_costs(lateral: float, heading_error: float, curvature: float, omegas: np.ndarray, speeds: np.ndarray,
                  horizon: float, step: float = 0.05, progress_weight: float = 0.0) -> np.ndarray:
    """Cost of each candidate (ω [rad/s], v [m/s]) held for ``horizon`` [s] from the given lane pose (Euler steps
    of ``step`` [s]); arrays of candidates broadcast together."""
    omegas, speeds = np.broadcast_arrays(np.asarray(omegas, float), np.asarray(speeds, float))
    e = np.full(omegas.shape, float(lateral))
    psi = np.full(omegas.shape, float(heading_error))
    cost = np.zeros(omegas.shape)
    n = max(1, round(horizon / step))
    for _ in range(n):
        scale = np.maximum(1.0 - curvature * e, 0.2)
        e = e + step * speeds * np.sin(psi)
        psi = psi + step * (omegas - speeds * curvature * np.cos(psi) / scale)
        cost += step * ((e / 0.03) ** 2 + (psi / 0.3) ** 2 + 200.0 * (np.abs(e) > _LANE_EDGE))
        cost -= step * progress_weight * speeds * np.cos(psi) / scale
    return cost


class ArcSamplerAgent(Agent):
    """Receding-horizon choice among ``n_arcs`` turn rates in ±``max_turn`` [rad/s] and the given ``speeds``
    [m/s], each rolled out for ``horizon`` [s]; ``smoothness`` weighs changes of the turn rate [per (rad/s)²]."""

    privileged = True
    name = "mpc"

    def __init__(self, horizon: float = 0.8, speeds: tuple[float, ...] = (0.3,), n_arcs: int = 25,
                 max_turn: float = 4.0, smoothness: float = 0.02, progress_weight: float = 0.0):
        if horizon <= 0 or n_arcs < 3 or max_turn <= 0 or not speeds or min(speeds) <= 0:
            raise ValueError(f"need horizon > 0, n_arcs >= 3, max_turn > 0 and positive speeds; got horizon="
                             f"{horizon}, n_arcs={n_arcs}, max_turn={max_turn}, speeds={speeds}")
        self.horizon, self.smoothness, self.progress_weight = horizon, smoothness, progress_weight
        om, sp = np.meshgrid(np.linspace(-max_turn, max_turn, n_arcs), np.asarray(speeds, float), indexing="ij")
        self._omegas, self._speeds = om.ravel(), sp.ravel()
        self._last = 0.0

    def reset(self, seed: int, episode: str | None = None) -> None:
        self._last = 0.0

    def act(self, obs: Observation) -> np.ndarray:
        lp = self.true_lane_pose(obs)
        if not lp.valid:
            return np.zeros(2)
        cost = rollout_costs(lp.lateral, lp.heading_error, lp.curvature, self._omegas, self._speeds, self.horizon,
                             progress_weight=self.progress_weight)
        cost = cost + self.smoothness * (self._omegas - self._last) ** 2
        best = int(np.argmin(cost))
        self._last = float(self._omegas[best])
        if not math.isfinite(self._last):
            return np.zeros(2)
        return wheels_for(float(self._speeds[best]), self._last)
