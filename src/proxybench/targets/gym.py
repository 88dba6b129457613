"""gym-duckietown targets with hidden parameters: a family of another simulator's robots, black boxes until reveal.

Each target is a robot node (``proxybench gym serve --param-file FILE --secret``): gym-duckietown's renderer and
DB18 dynamics with θ (under gym's own names: ``trim``, ``delay``, ``cam_angle``, ``cam_height``, ...) drawn from a
seed into a file only the node and :meth:`GymTarget.reveal` read (mode 600). The node reports only a hash of θ,
so nothing an experiment sees — reports, recordings, trajectories — holds the values until scoring reveals them.
"""

from __future__ import annotations

import secrets
import sys
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from proxybench.targets.robot import RobotTarget

__all__ = ["GymTarget", "draw_gym", "gym_targets"]


def draw_gym(seed: int, index: int, ranges: dict[str, tuple[float, float]]) -> dict[str, float]:
    """θ of gym target ``index`` (gym's parameter names), drawn uniformly in ``ranges``; a pure function of
    (seed, index, ranges)."""
    rng = np.random.default_rng([seed, index, 0x6E])
    return {name: float(rng.uniform(lo, hi)) for name, (lo, hi) in ranges.items()}


class GymTarget(RobotTarget):
    """One gym-duckietown node whose θ sits in ``param_file``; ``reveal()`` reads it once every episode ran."""

    def __init__(self, name: str, param_file: Path, nodes: int = 1, frame_rate: float = 15.0):
        command = f"{sys.executable} -m proxybench gym serve --param-file {param_file} --secret"
        super().__init__(command, nodes=nodes, frame_rate=frame_rate)
        self.name = name
        self.param_file = param_file

    def reveal(self) -> dict[str, Any]:
        values = yaml.safe_load(self.param_file.read_text(encoding="utf-8")) or {}
        values.pop("nonce", None)
        return values


def gym_targets(n: int, seed: int, ranges: dict[str, tuple[float, float]], folder: Path, *,
                nodes: int = 1, indices: list[int] | None = None) -> list[GymTarget]:
    """``n`` gym targets with θ drawn from ``seed`` (target k is draw ``indices[k]``, by default draw k); their
    parameter files are written into ``folder`` (mode 700, each file 600; kept, with their nonces, when a study
    resumes)."""
    from proxybench.gym.params import load_param_file

    if n < 1:
        raise ValueError(f"targets: need at least 1 gym target, got {n}")
    folder.mkdir(parents=True, exist_ok=True, mode=0o700)
    out = []
    for k in range(n):
        path = folder / f"gym-{k:03d}.yaml"
        theta = draw_gym(seed, k if indices is None else indices[k], ranges)
        if not path.exists() or load_param_file(path)[0] != theta:
            path.write_text(yaml.safe_dump({**theta, "nonce": secrets.token_hex(16)}))
            path.chmod(0o600)
        load_param_file(path)  # a drawn value gym would refuse fails here, naming it, before any episode
        out.append(GymTarget(f"gym-{k}", path, nodes))
    return out
