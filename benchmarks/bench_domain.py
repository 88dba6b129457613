"""Domain speed: the three figures issue 2 sets targets for, as a table.

    .venv/bin/python benchmarks/bench_domain.py            # full (about a minute)
    .venv/bin/python benchmarks/bench_domain.py --quick    # fewer steps

Each figure is the median of 3 runs, driven by the privileged PID controller (as the gym-duckietown
reference figures were), after a warm-up that compiles the kernels. Targets (2 cores, no GPU):
single env 640×480 without blur ≥ 500 steps/s; N = 64 at 80×60 ≥ 25,000 env-steps/s; physics + lane
pose without rendering ≥ 1,000,000 env-steps/s.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import statistics
import time

import numba
import numpy as np
from rich.console import Console
from rich.table import Table

from proxybench.agents.pid import wheels_for
from proxybench.domain.env import LaneFollowingEnv, LaneFollowingVectorEnv
from proxybench.domain.lane_pose import LP
from proxybench.domain.maps import Map, MapObject, load_map
from proxybench.domain.params import DomainParams
from proxybench.domain.simulator import Simulator


def pid_actions(lateral: np.ndarray, heading: np.ndarray) -> np.ndarray:
    """Vectorised PD lane keeping on (N,) lane errors → (N, 2) PWM."""
    lateral = np.nan_to_num(lateral)
    heading = np.nan_to_num(heading)
    omega = -(10.0 * lateral + 4.0 * heading)
    return np.stack([wheels_for(0.3, float(w)) for w in omega]) if lateral.size < 8 else np.clip(
        np.stack([0.5 * (1.0 - omega * 4 / 15), 0.5 * (1.0 + omega * 4 / 15)], axis=1), -1, 1)


def loop_with_objects() -> Map:
    """loop_3x3 with 10 objects along the roadsides (inside and outside the loop)."""
    kinds = ["duckie", "cone", "sign_stop", "duckiebot", "barrier", "duckie", "cone", "duckie", "sign_left", "duckie"]
    spots = [(0.65, 0.88), (1.1, 0.88), (0.88, 0.65), (0.88, 1.1), (0.03, 0.88), (1.72, 0.88), (0.88, 0.03),
             (0.88, 1.72), (0.1, 0.1), (1.65, 1.65)]
    objs = tuple(MapObject(k, x, y, heading=math.pi / 2 if k == "barrier" else 0.0) for k, (x, y) in zip(kinds, spots,
                                                                                                       strict=True))
    return dataclasses.replace(load_map("loop_3x3"), objects=objs)


def bench_single(steps: int, width: int, height: int, blur: float, map_: Map | str = "loop_3x3") -> float:
    env = LaneFollowingEnv(map_, params=DomainParams(image_width=width, image_height=height, blur_time=blur))
    env.reset(seed=0)
    for _ in range(20):
        env.step(np.array([0.3, 0.3]))
    env.reset(seed=1)
    lp = env.sim.lane
    t0 = time.perf_counter()
    for _ in range(steps):
        a = pid_actions(lp[:1, LP.LATERAL], lp[:1, LP.HEADING_ERROR])[0]
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset()
    return steps / (time.perf_counter() - t0)


def bench_vector(steps: int, n: int, width: int, height: int, blur: float) -> float:
    env = LaneFollowingVectorEnv(num_envs=n, params=DomainParams(image_width=width, image_height=height,
                                                                 blur_time=blur))
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.full((n, 2), 0.3))
    lp = env.sim.lane
    t0 = time.perf_counter()
    for _ in range(steps):
        env.step(pid_actions(lp[:, LP.LATERAL], lp[:, LP.HEADING_ERROR]))
    return n * steps / (time.perf_counter() - t0)


def bench_physics(steps: int, n: int) -> float:
    sim = Simulator("loop_3x3", DomainParams(), n=n, render=False)
    sim.step(np.zeros((n, 2)))
    lp = sim.lane
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step(pid_actions(lp[:, LP.LATERAL], lp[:, LP.HEADING_ERROR]))
    return n * steps / (time.perf_counter() - t0)


def median3(fn, *args) -> float:
    return statistics.median(fn(*args) for _ in range(3))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer steps (for smoke tests)")
    args = ap.parse_args()
    k = 0.1 if args.quick else 1.0
    rows = [
        ("single env, 640×480, no blur", "steps/s", median3(bench_single, int(1800 * k), 640, 480, 0.0), 500, 50),
        ("single env, 640×480, no blur, 10 objects", "steps/s",
         median3(bench_single, int(1800 * k), 640, 480, 0.0, loop_with_objects()), None, 50),
        ("single env, 640×480, blur 0.05 s ×3", "steps/s", median3(bench_single, int(900 * k), 640, 480, 0.05), None,
         50),
        ("single env, 160×120, no blur", "steps/s", median3(bench_single, int(1800 * k), 160, 120, 0.0), None, 250),
        ("batched N=64, 80×60, no blur", "env-steps/s", median3(bench_vector, int(300 * k), 64, 80, 60, 0.0), 25_000,
         250),
        ("batched N=64, 80×60, blur 0.05 s ×3", "env-steps/s", median3(bench_vector, int(200 * k), 64, 80, 60, 0.05),
         None, 250),
        ("physics + lane pose, N=4096, no rendering", "env-steps/s", median3(bench_physics, int(300 * k), 4096),
         1_000_000, 500),
    ]
    table = Table(title=f"proxybench domain speed — {os.cpu_count()} cores, numba {numba.__version__} "
                        f"({numba.config.NUMBA_NUM_THREADS} threads)")
    for col in ("case", "unit", "proxybench", "target", "gym-duckietown ref", "× ref"):
        table.add_column(col, justify="left" if col == "case" else "right")
    for name, unit, value, target, ref in rows:
        ok = "" if target is None else (" ✓" if value >= target else " ✗")
        table.add_row(name, unit, f"{value:,.0f}", f"{target:,}{ok}" if target else "–", f"{ref:,}",
                      f"{value / ref:,.0f}×")
    Console(width=130).print(table)


if __name__ == "__main__":
    main()
