"""A real behaviour-cloning checkpoint for tests: an untrained tiny network (camera only, driving badly)."""

from __future__ import annotations

from pathlib import Path

import pytest


def untrained_checkpoint(folder: Path) -> Path:
    """``folder/bc.pt``: a tiny untrained network saved as a checkpoint agent (skips the test without PyTorch)."""
    pytest.importorskip("torch")
    from proxybench.learning.model import ModelConfig
    from proxybench.learning.training import build_model, save_checkpoint

    model = build_model(ModelConfig(width=32, height=24, channels=(4, 4, 4, 4, 4), hidden=(8,)), device="cpu")
    return save_checkpoint(folder / "bc.pt", model)
