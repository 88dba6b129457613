"""Training from scratch, fine-tuning, and checkpoints (``NAME.pt`` state_dict + ``NAME.json`` config).

One function, :func:`train`, serves both uses: from scratch it starts from a freshly initialised
network, for fine-tuning from a loaded checkpoint (pre-trained on proxy data) — usually with a smaller
learning rate. The number of gradient steps grows with the data (``epochs`` passes) but is bounded
below, so that tiny data sets are still fitted, and above, so that a learning-curve ladder has a
predictable cost. Everything random (initialisation, minibatch order) follows ``seed``.

A checkpoint is two files: the weights as a PyTorch ``state_dict`` (loaded with ``weights_only=True``,
so loading never runs code from the file) and a JSON record of the architecture, training settings and
data provenance. The JSON alone rebuilds the network.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from proxybench import __version__
from proxybench.learning.configs import TrainConfig
from proxybench.learning.dataset import Dataset
from proxybench.learning.model import ModelConfig, PilotNet, default_device, to_input

__all__ = ["CHECKPOINT_FORMAT", "TrainConfig", "TrainResult", "build_model", "dataset_loss", "load_checkpoint",
           "save_checkpoint", "train"]

CHECKPOINT_FORMAT = "proxybench-bc-checkpoint"


@dataclass
class TrainResult:
    """Loss curve (mean minibatch loss per ``log_every`` steps), cost and throughput of one training run."""

    losses: list[float]
    steps: int
    samples: int
    wall_s: float
    device: str
    history: list[dict[str, Any]] = field(default_factory=list)

    @property
    def samples_per_s(self) -> float:
        return self.samples_seen / max(self.wall_s, 1e-9)

    @property
    def samples_seen(self) -> int:
        return sum(h["samples_seen"] for h in self.history) if self.history else 0


def build_model(cfg: ModelConfig, seed: int = 0, device: torch.device | str | None = None) -> PilotNet:
    """A freshly initialised network (initialisation seeded)."""
    torch.manual_seed(seed)
    return PilotNet(cfg).to(device or default_device())


def _batches(n: int, batch: int, steps: int, gen: torch.Generator):
    """Minibatch indices: shuffled epochs, concatenated, cut into ``steps`` batches."""
    need = steps * batch
    perms = [torch.randperm(n, generator=gen) for _ in range(math.ceil(need / n))]
    flat = torch.cat(perms)[:need]
    return flat.view(steps, batch)


def train(model: PilotNet, data: Dataset, cfg: TrainConfig, progress=None) -> TrainResult:
    """Fit ``model`` to the expert labels of ``data`` in place (MSE); returns the loss curve.

    ``progress(step, steps)`` is called every ``log_every`` steps.
    """
    if len(data) == 0:
        raise ValueError("cannot train on an empty dataset")
    device = next(model.parameters()).device
    images = torch.from_numpy(np.ascontiguousarray(data.images)).to(device)
    labels = model.targets(torch.from_numpy(data.actions.astype(np.float32)).to(device))
    steps = cfg.steps_for(len(data))
    gen = torch.Generator().manual_seed(cfg.seed)
    torch.manual_seed(cfg.seed)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.LambdaLR(
        opt, lambda s: cfg.lr_final_fraction + (1 - cfg.lr_final_fraction) * 0.5 * (1 + math.cos(math.pi * s / steps)))
    batch = min(cfg.batch_size, len(data))
    model.train()
    losses, window = [], []
    t0 = time.perf_counter()
    for s, idx in enumerate(_batches(len(data), batch, steps, gen)):
        idx = idx.to(device)
        x = to_input(images[idx], model.cfg, device)
        loss = nn.functional.mse_loss(model(x), labels[idx])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        sched.step()
        window.append(float(loss.detach()))
        if (s + 1) % cfg.log_every == 0 or s + 1 == steps:
            losses.append(float(np.mean(window)))
            window = []
            if progress:
                progress(s + 1, steps)
    model.eval()
    wall = time.perf_counter() - t0
    return TrainResult(losses, steps, len(data), wall, str(device),
                       [{"samples": len(data), "steps": steps, "samples_seen": steps * batch, "config": asdict(cfg)}])


@torch.no_grad()
def dataset_loss(model: PilotNet, data: Dataset, batch: int = 512) -> float:
    """Mean squared error of ``model`` on ``data`` (evaluation mode)."""
    device = next(model.parameters()).device
    model.eval()
    total = 0.0
    for lo in range(0, len(data), batch):
        x = to_input(data.images[lo:lo + batch], model.cfg, device)
        y = model.targets(torch.from_numpy(data.actions[lo:lo + batch].astype(np.float32)).to(device))
        total += float(nn.functional.mse_loss(model(x), y, reduction="sum")) / 2
    return total / max(len(data), 1)


def save_checkpoint(path: str | Path, model: PilotNet, info: dict[str, Any] | None = None) -> Path:
    """Write ``path`` (.pt weights) and its ``.json`` sidecar; returns the .pt path."""
    path = Path(path)
    if path.suffix != ".pt":
        path = path.with_suffix(".pt")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp")
    torch.save({k: v.detach().cpu() for k, v in model.state_dict().items()}, tmp)
    tmp.replace(path)
    side = {"format": CHECKPOINT_FORMAT, "version": 1, "proxybench_version": __version__,
            "model": model.cfg.to_dict(), **(info or {})}
    path.with_suffix(".json").write_text(json.dumps(side, indent=1, default=str))
    return path


def load_checkpoint(path: str | Path, device: torch.device | str | None = None) -> tuple[PilotNet, dict[str, Any]]:
    """The network of a checkpoint (evaluation mode) and its JSON record."""
    path = Path(path)
    if path.suffix != ".pt":
        path = path.with_suffix(".pt")
    side_path = path.with_suffix(".json")
    if not path.exists() or not side_path.exists():
        raise FileNotFoundError(f"{path}: a checkpoint needs both {path.name} and {side_path.name}")
    info = json.loads(side_path.read_text())
    if info.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{side_path}: format {info.get('format')!r}, expected {CHECKPOINT_FORMAT!r}")
    model = PilotNet(ModelConfig.from_dict(info["model"]))
    model.load_state_dict(torch.load(path, map_location="cpu", weights_only=True))
    model.to(device or default_device()).eval()
    return model, info
