"""Learning throughput: training samples/s of the PilotNet-style CNN, and dataset generation rate.

    .venv/bin/python benchmarks/bench_learning.py            # ~2 minutes on 2 cores
    .venv/bin/python benchmarks/bench_learning.py --quick    # ~30 s

Training: ``train()`` on random frames (the same work as real ones: uint8 → float conversion,
forward, backward, Adam step), batch 64, at 64×48, 80×60 and 160×120, after a few warm-up steps. Generation:
the privileged expert drives 32 robots at once in the reality model (rendering, physics, lane pose,
expert labels, noise injection), then the dataset is written as compressed NPZ shards. Inference: one
``BCAgent.act`` call per frame, as the runner and the protocol use it.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np

# importing proxybench.learning first sets OMP_WAIT_POLICY=PASSIVE before PyTorch loads (see its docstring)
from proxybench.agents.base import Observation
from proxybench.learning.agent import BCAgent
from proxybench.learning.collection import collect
from proxybench.learning.configs import CollectConfig
from proxybench.learning.dataset import ARRAYS, Dataset
from proxybench.learning.domains import reality_domain
from proxybench.learning.model import ModelConfig, configure_threads, default_device
from proxybench.learning.training import TrainConfig, build_model, train


def _random_dataset(n: int, w: int, h: int) -> Dataset:
    rng = np.random.default_rng(0)
    arrays = {"images": rng.integers(0, 256, (n, h, w, 3), dtype=np.uint8),
              "actions": rng.uniform(-1, 1, (n, 2)).astype(np.float32)}
    arrays["executed"] = arrays["actions"].copy()
    arrays |= {"episode": np.zeros(n, np.int32), "frame": np.arange(n, dtype=np.int32),
               "on_policy": np.zeros(n, bool)}
    assert set(arrays) == set(ARRAYS)
    return Dataset(arrays, {"episodes": [{"id": 0}]})


def bench_train(w: int, h: int, steps: int) -> tuple[float, int]:
    """Samples/s of training at w×h (after warm-up) and the network's parameter count."""
    model = build_model(ModelConfig(width=w, height=h))
    data = _random_dataset(2048, w, h)
    train(model, data, TrainConfig(min_steps=3, max_steps=3))
    res = train(model, data, TrainConfig(min_steps=steps, max_steps=steps, log_every=steps))
    return res.samples_per_s, sum(p.numel() for p in model.parameters())


def bench_generate(w: int, h: int, samples: int) -> tuple[float, float]:
    """Samples/s of expert data collection (32 robots, reality model) and of writing compressed shards."""
    dom = reality_domain(w, h)
    collect(dom, CollectConfig(samples=64, robots=32))  # compile / warm caches
    t0 = time.perf_counter()
    data = collect(dom, CollectConfig(samples=samples, robots=32))
    gen = samples / (time.perf_counter() - t0)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        data.save(tmp + "/ds")
        save = samples / (time.perf_counter() - t0)
    return gen, save


def bench_act(w: int, h: int, frames: int) -> float:
    """Frames/s of one-at-a-time ``BCAgent.act`` (the runner's and the protocol's path)."""
    agent = BCAgent(build_model(ModelConfig(width=w, height=h)))
    img = np.zeros((h, w, 3), np.uint8)
    agent.act(Observation(img, 0.0))
    t0 = time.perf_counter()
    for _ in range(frames):
        agent.act(Observation(img, 0.0))
    return frames / (time.perf_counter() - t0)


def main() -> None:
    import torch
    from rich.console import Console
    from rich.table import Table

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    threads = configure_threads()
    steps, samples, frames = (10, 1000, 100) if args.quick else (40, 6000, 500)
    dev = default_device()
    table = Table(title=f"learning — {os.cpu_count()} cores, torch {torch.__version__} with {threads} threads on "
                        f"{dev}, OMP_WAIT_POLICY={os.environ.get('OMP_WAIT_POLICY')}, load {os.getloadavg()[0]:.1f}")
    sizes = ((64, 48), (80, 60), (160, 120))  # 64×48: the full PLV experiment's frames
    for col in ("case", *(f"{w}×{h}" for w, h in sizes)):
        table.add_column(col, justify="left" if col == "case" else "right")
    tr = [bench_train(w, h, steps) for w, h in sizes]
    table.add_row("training, batch 64 (samples/s)", *(f"{s:,.0f}" for s, _ in tr))
    table.add_row("network parameters", *(f"{p:,}" for _, p in tr))
    gen = [bench_generate(w, h, samples) for w, h in sizes]
    table.add_row("dataset generation, 32 robots, reality model (samples/s)", *(f"{g:,.0f}" for g, _ in gen))
    table.add_row("writing compressed NPZ shards (samples/s)", *(f"{s:,.0f}" for _, s in gen))
    table.add_row("BCAgent.act, one frame per call (frames/s)", *(f"{bench_act(w, h, frames):,.0f}"
                                                                  for w, h in sizes))
    Console(width=140).print(table)


if __name__ == "__main__":
    main()
