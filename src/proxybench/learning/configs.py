"""The settings of behaviour cloning and of its data collection and scoring: plain data.

:class:`ModelConfig` (the network), :class:`TrainConfig` (optimiser and schedule), :class:`CollectConfig` (how
the expert records data, :mod:`proxybench.learning.collection`) and :class:`EvalConfig` (evaluation episodes,
:mod:`proxybench.learning.evaluation`) live here, apart from the code that uses them, so that a study's config
(the PLV experiment's) and the command line generated from it need neither PyTorch nor the simulator.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

__all__ = ["CollectConfig", "EvalConfig", "ModelConfig", "TrainConfig"]


@dataclass(frozen=True)
class ModelConfig:
    """Architecture and input of the network; stored in every checkpoint's JSON."""

    width: int = 80  # input image width [px]
    height: int = 60  # input image height [px]
    channels: tuple[int, ...] = (24, 36, 48, 64, 64)  # the five convolutions (PilotNet's numbers)
    hidden: tuple[int, ...] = (100, 50, 10)  # fully connected layers
    output: str = "wheels"  # "wheels": PWM (left, right); "vw": (v, ω) then nominal PWM

    def __post_init__(self) -> None:
        if self.output not in ("wheels", "vw"):
            raise ValueError(f"output must be 'wheels' or 'vw', got {self.output!r}")
        if len(self.channels) != 5:
            raise ValueError(f"PilotNet has five convolutions, got channels={self.channels}")
        if self.width < 16 or self.height < 12:
            raise ValueError(f"input {self.width}×{self.height} is too small (at least 16×12)")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> ModelConfig:
        return cls(**{**d, "channels": tuple(d["channels"]), "hidden": tuple(d["hidden"])})


@dataclass(frozen=True)
class TrainConfig:
    """Optimiser and schedule. Steps = clamp(ceil(epochs · n / batch_size), min_steps, max_steps)."""

    epochs: float = 15.0
    min_steps: int = 150
    max_steps: int = 2000
    batch_size: int = 64
    lr: float = 1e-3  # Adam; decays by cosine to lr_final_fraction · lr
    lr_final_fraction: float = 0.05
    weight_decay: float = 0.0
    seed: int = 0
    log_every: int = 25  # steps between recorded losses

    def steps_for(self, n: int) -> int:
        """Gradient steps used for a data set of ``n`` samples."""
        return int(min(self.max_steps, max(self.min_steps, math.ceil(self.epochs * n / self.batch_size))))


@dataclass(frozen=True)
class CollectConfig:
    """How data is recorded. Seeds: episode e of a collection with ``seed`` s uses seed (s, e)."""

    samples: int
    robots: int = 32
    episode_frames: int = 75  # 5 s at 15 Hz: short episodes, many different starts
    start_lateral: float = 0.08  # [m] start offset bound (evaluation uses 0.04)
    start_heading: float = 0.5  # [rad] start heading error bound (evaluation uses 0.35)
    noise_std: float = 0.15  # [PWM] std of the noise added to the executed expert command
    noise_corr: float = 0.85  # frame-to-frame correlation of that noise (AR(1)); drifts, not jitter
    map: str = "loop_3x3"
    seed: int = 0

    def __post_init__(self) -> None:
        if self.samples < 1 or self.robots < 1 or self.episode_frames < 1:
            raise ValueError("samples, robots and episode_frames must be positive")
        if not 0.0 <= self.noise_corr < 1.0:
            raise ValueError(f"noise_corr must be in [0, 1), got {self.noise_corr}")


@dataclass(frozen=True)
class EvalConfig:
    """Evaluation episodes: episode e uses simulator seed ``seed + e`` (never a data-collection seed)."""

    episodes: int = 6
    seconds: float = 30.0
    map: str = "loop_3x3"
    seed: int = 100_000
    metric: str = "lane_score"
