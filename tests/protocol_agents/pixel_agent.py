"""Agents whose commands depend on every input bit, served as nodes by the protocol tests.

``python pixel_agent.py [pixel|privileged|chatty|failing]`` serves one of them with
:func:`proxybench.protocol.serve`; the tests also import the classes to run them in-process and compare.
"""

from __future__ import annotations

import sys

import numpy as np

from proxybench.agents.base import Agent, Observation
from proxybench.protocol import serve


class PixelAgent(Agent):
    """Commands from a seeded random projection of all pixels, the odometry and the time."""

    name = "pixel"

    def reset(self, seed: int, episode: str | None = None) -> None:
        self._rng = np.random.default_rng(seed)
        self._w: np.ndarray | None = None

    def act(self, obs: Observation) -> np.ndarray:
        s = 0.0
        if obs.camera is not None:
            if self._w is None or self._w.shape != obs.camera.shape:
                self._w = self._rng.normal(size=obs.camera.shape)
            s = float((obs.camera * self._w).sum()) / obs.camera.size
        odo = sum(obs.odometry) if obs.odometry is not None else 0.0
        return np.tanh(np.array([s + odo + obs.time, s - odo - (obs.odometry_resolution or 0.0)]))


class PrivilegedPixelAgent(PixelAgent):
    """PixelAgent plus the true lane pose."""

    privileged = True
    name = "privileged-pixel"

    def act(self, obs: Observation) -> np.ndarray:
        lp = obs.lane_pose
        if lp is None:
            raise ValueError("privileged agent got no lane pose")
        extra = lp.lateral + lp.heading_error + lp.along + lp.curvature + lp.segment + lp.tile[0] + lp.in_lane
        return np.tanh(super().act(obs) + extra)


class ChattyAgent(PixelAgent):
    """Prints to stdout at every step: serve must keep the protocol stream clean anyway."""

    def act(self, obs: Observation) -> np.ndarray:
        print("chatty agent says hello on stdout")
        return super().act(obs)


class FailingAgent(PixelAgent):
    """Raises at the third command."""

    def reset(self, seed: int, episode: str | None = None) -> None:
        super().reset(seed, episode)
        self._n = 0

    def act(self, obs: Observation) -> np.ndarray:
        self._n += 1
        if self._n == 3:
            raise RuntimeError("failing agent gives up")
        return super().act(obs)


AGENTS = {"pixel": PixelAgent, "privileged": PrivilegedPixelAgent, "chatty": ChattyAgent, "failing": FailingAgent}

if __name__ == "__main__":
    serve(AGENTS[sys.argv[1] if len(sys.argv) > 1 else "pixel"]())
