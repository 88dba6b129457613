"""What the agent sandbox costs: node start (to the end of the protocol handshake) and the step round trip.

The same agent node (``python -m proxybench.protocol straight``: imports proxybench, a trivial ``act``) is
started and driven three ways, alternately, so that a noisy machine affects each alike:

- ``plain``: a child process of this one (no sandbox at all; what the evaluator did for built-in agents
  before packages existed);
- ``none``: through the exec shim without namespaces (limits and clean environment only);
- ``bwrap``: the evaluator's sandbox (agent user, staged runtime, bubblewrap namespaces), when this host
  has it (run as root after ``proxybench sandbox setup``).

Start times are medians over ``--starts`` starts; step times medians over ``--steps`` steps at 160×120
(observations + get_commands in one write, the JPEG encoded beforehand).
Run: ``python benchmarks/bench_sandbox.py [--quick]``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

import numpy as np

from proxybench.agents.base import Observation
from proxybench.evaluator.sandbox import Isolation, Limits, confine, detect_isolation
from proxybench.protocol import AgentProcess, jpeg

NODE = ["python3", "-m", "proxybench.protocol", "straight"]


def commands(folder: str) -> dict[str, list[str]]:
    out = {"plain": [sys.executable, *NODE[1:]],
           "none": confine(NODE, folder, Limits(), Isolation("none", "me", runtime=(), pythonpath=""), parent=None)}
    isolation = detect_isolation()
    if isolation.safe:
        out["bwrap"] = confine(NODE, folder, Limits(), isolation, parent=None)
    else:
        print(f"(no bwrap row: {isolation.problem})")
    return out


def start_s(argv: list[str]) -> float:
    t0 = time.perf_counter()
    with AgentProcess(argv, init_timeout=60) as proc:
        proc.seed(0)
        proc.episode_start("bench")
        return time.perf_counter() - t0


def step_ms(argv: list[str], steps: int) -> float:
    rng = np.random.default_rng(0)
    image = rng.integers(0, 255, (120, 160, 3), dtype=np.uint8)
    encoded = jpeg.encode(image)
    with AgentProcess(argv, init_timeout=60) as proc:
        proc.seed(0)
        proc.episode_start("bench")
        times = []
        for i in range(steps + 20):
            t0 = time.perf_counter()
            proc.step(Observation(image, i * 0.05, (0.0, 0.0), 0.01), encoded)
            if i >= 20:
                times.append(time.perf_counter() - t0)
    return 1000 * statistics.median(times)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true")
    p.add_argument("--starts", type=int, default=7)
    p.add_argument("--steps", type=int, default=500)
    args = p.parse_args()
    starts, steps = (3, 100) if args.quick else (args.starts, args.steps)
    with tempfile.TemporaryDirectory() as folder:
        os.chmod(folder, 0o755)
        cmds = commands(folder)
        start = {k: [] for k in cmds}
        for _ in range(starts):
            for kind, argv in cmds.items():
                start[kind].append(start_s(argv))
        step = {kind: step_ms(argv, steps) for kind, argv in cmds.items()}
    print(f"{'way':6s} {'start + handshake [s], median':>30s} {'step round trip [ms], median':>30s}")
    for kind in cmds:
        print(f"{kind:6s} {statistics.median(start[kind]):30.3f} {step[kind]:30.3f}")
    print(f"({starts} starts, {steps} steps each, 160×120 JPEG; cores: {os.cpu_count()}, "
          f"load average {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
