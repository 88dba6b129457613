"""A trained behaviour-cloning network as an agent: ``BCAgent(checkpoint)`` drives like any zoo agent.

It reads the camera only (not privileged), so it runs in proxies, in the reality model, through the
runner and behind the AIDO protocol alike. ``policy`` is the batched form (frames of N robots → N
commands) that evaluation and DAgger use to step a whole simulator batch per network call.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from proxybench.agents.base import Agent, Observation
from proxybench.learning.model import PilotNet, to_input
from proxybench.learning.training import load_checkpoint

__all__ = ["BCAgent", "make_bc_agent", "torch_policy"]


def torch_policy(model: PilotNet):
    """``images (N, H, W, 3) uint8 → PWM (N, 2)`` for a network, without gradients."""
    device = next(model.parameters()).device

    @torch.no_grad()
    def policy(images: np.ndarray) -> np.ndarray:
        model.eval()
        out = model.to_pwm(model(to_input(images, model.cfg, device)))
        return out.cpu().numpy().astype(np.float64)

    return policy


class BCAgent(Agent):
    """Camera frame → wheel PWM by a behaviour-cloned network (from a checkpoint path or a live model)."""

    privileged = False

    def __init__(self, checkpoint: str | Path | PilotNet, device: str | torch.device | None = None,
                 name: str | None = None):
        if isinstance(checkpoint, PilotNet):
            self.model, self.info = checkpoint, {}
            default = "bc"
        else:
            self.model, self.info = load_checkpoint(checkpoint, device)
            default = f"bc:{Path(checkpoint).stem}"
        self.name = name or default
        self._policy = torch_policy(self.model)

    def act(self, obs: Observation) -> np.ndarray:
        if obs.camera is None:
            raise ValueError(f"{self.name} drives from the camera: the observation has no frame")
        return self._policy(obs.camera[None])[0]

    def policy(self, images: np.ndarray) -> np.ndarray:
        """Batched commands (N, 2) for frames (N, H, W, 3)."""
        return self._policy(images)


def make_bc_agent(path: str | Path) -> BCAgent:
    """The loader the zoo and the command line use for a checkpoint path (``.pt`` with its ``.json``)."""
    return BCAgent(path)
