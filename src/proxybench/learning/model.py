"""The end-to-end driving network: a small NVIDIA-style ("PilotNet") CNN, camera frame → wheel commands.

Bojarski et al. (2016) drove a car with five convolutions (5×5 stride 2 three times, then 3×3) and a
few fully connected layers straight from pixels. This is the same shape, scaled to Duckietown's small
frames: padded convolutions so that 40×30 up to 640×480 inputs work, and a configurable width. The
output is either wheel PWM (left, right) — the command the agent contract speaks — or the (v, ω) the
expert demanded, mapped to PWM by the nominal DB18 steady state.

>>> import torch
>>> net = PilotNet(ModelConfig(width=40, height=30))
>>> tuple(net(torch.zeros(2, 3, 30, 40)).shape)
(2, 2)
"""

from __future__ import annotations

import itertools
import os

import numpy as np
import torch
from torch import nn

from proxybench.learning.configs import ModelConfig

__all__ = ["ModelConfig", "PilotNet", "configure_threads", "default_device", "to_input"]

_VW_SCALE = (0.35, 3.0)  # typical magnitudes of v [m/s] and ω [rad/s], so both outputs are O(1)


class PilotNet(nn.Module):
    """Normalised RGB (B, 3, H, W) → (B, 2): PWM, or (v, ω) / scale, depending on ``cfg.output``."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        c = (3, *cfg.channels)
        layers: list[nn.Module] = []
        for k in range(5):
            big = k < 3  # three 5×5 stride-2 convolutions, then two 3×3
            layers += [nn.Conv2d(c[k], c[k + 1], 5 if big else 3, 2 if big else 1, 2 if big else 1), nn.ELU()]
        self.features = nn.Sequential(*layers, nn.Flatten())
        with torch.no_grad():
            n = self.features(torch.zeros(1, 3, cfg.height, cfg.width)).shape[1]
        dims = (n, *cfg.hidden)
        head: list[nn.Module] = []
        for a, b in itertools.pairwise(dims):
            head += [nn.Linear(a, b), nn.ELU()]
        self.head = nn.Sequential(*head, nn.Linear(dims[-1], 2))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(x))

    def targets(self, pwm: torch.Tensor) -> torch.Tensor:
        """What the network is trained to output for expert PWM labels (B, 2)."""
        if self.cfg.output == "wheels":
            return pwm
        total, diff = pwm[:, 0] + pwm[:, 1], pwm[:, 1] - pwm[:, 0]
        v, w = total * 1.5 / 5.0, diff * 15.0 / 4.0  # the inverse of the nominal steady state
        return torch.stack([v / _VW_SCALE[0], w / _VW_SCALE[1]], dim=1)

    def to_pwm(self, out: torch.Tensor) -> torch.Tensor:
        """Network output (B, 2) → wheel PWM (B, 2) in [-1, 1]."""
        if self.cfg.output == "vw":
            total = out[:, 0] * _VW_SCALE[0] * 5.0 / 1.5
            diff = out[:, 1] * _VW_SCALE[1] * 4.0 / 15.0
            out = torch.stack([0.5 * (total - diff), 0.5 * (total + diff)], dim=1)
        return out.clamp(-1.0, 1.0)


def to_input(images: np.ndarray | torch.Tensor, cfg: ModelConfig, device: torch.device | str = "cpu") -> torch.Tensor:
    """uint8 frames (B, H, W, 3) → float (B, 3, h, w) in [-0.5, 0.5] at the network's size.

    Frames of another size are resampled (area averaging when shrinking), so a network trained at
    80×60 also drives a robot whose camera delivers 640×480.
    """
    if isinstance(images, np.ndarray) and not images.flags.writeable:  # e.g. a frame read from a node's message:
        images = images.copy()  # torch cannot share read-only memory (it warns); frames are small
    x = torch.as_tensor(images).to(device)
    if x.ndim == 3:
        x = x[None]
    x = x.permute(0, 3, 1, 2).float().div_(255.0).sub_(0.5)
    if x.shape[2:] != (cfg.height, cfg.width):
        mode = "area" if x.shape[2] >= cfg.height else "bilinear"
        x = nn.functional.interpolate(x, size=(cfg.height, cfg.width), mode=mode)
    return x


def default_device() -> torch.device:
    """A CUDA GPU when present, else the CPU."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def configure_threads(threads: int | None = None) -> int:
    """Use ``threads`` (default: every core) for PyTorch's CPU kernels; returns the number set."""
    n = max(1, threads or os.cpu_count() or 1)
    torch.set_num_threads(n)
    return n
