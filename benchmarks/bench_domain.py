"""Domain speed: the three figures issue 2 sets targets for, as a table.

    .venv/bin/python benchmarks/bench_domain.py            # full (about a minute)
    .venv/bin/python benchmarks/bench_domain.py --quick    # fewer steps

Each figure is the median of 3 runs, driven by the privileged PID controller (as the gym-duckietown
reference figures were), after a warm-up that compiles the kernels. Targets (2 cores, no GPU):
single env 640×480 without blur ≥ 500 steps/s; N = 64 at 80×60 ≥ 25,000 env-steps/s; physics + lane
pose without rendering ≥ 1,000,000 env-steps/s. With 10 map objects and 3 NPC robots per episode the
simulator may cost at most 2× the empty road (issue 8): the ``simulator, ...`` rows measure both side by side
and the last lines print the ratio.
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
from proxybench.domain.npcs import NpcRobot, Traffic
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


#: three NPC Duckiebots: one 0.6 m ahead in the robot's lane (in view), two anywhere on the lanes
THREE_NPCS = Traffic(robots=(NpcRobot(ahead=0.6), NpcRobot(), NpcRobot(driver="pure-pursuit")))


def bench_sim(steps: int, n: int, width: int, height: int, map_: Map | str = "loop_3x3",
              npcs: Traffic | None = None) -> float:
    """Env-steps/s of the simulator itself (render + step, PD on the egos and the NPC robots), any world."""
    sim = Simulator(map_, DomainParams(image_width=width, image_height=height, blur_time=0.0), n=n, npcs=npcs)
    for i in range(n):
        sim.reset(i, seed=i)
    sim.render()
    t0 = time.perf_counter()
    for k in range(steps):
        sim.render()
        npc = pid_actions(sim.npc_lane[:, LP.LATERAL], sim.npc_lane[:, LP.HEADING_ERROR]) if sim.worlds.k else None
        sim.step(pid_actions(sim.lane[:, LP.LATERAL], sim.lane[:, LP.HEADING_ERROR]), npc_commands=npc)
        if k % 150 == 149:  # fresh episodes now and then, as an env would after a crash
            for i in range(n):
                sim.reset(i, seed=k + i)
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
        ("simulator, 640×480, empty road", "steps/s", median3(bench_sim, int(900 * k), 1, 640, 480), None, 50),
        ("simulator, 640×480, 10 objects + 3 NPC robots", "steps/s",
         median3(bench_sim, int(900 * k), 1, 640, 480, loop_with_objects(), THREE_NPCS), None, 50),
        ("simulator N=64, 80×60, empty road", "env-steps/s", median3(bench_sim, int(150 * k), 64, 80, 60), None, 250),
        ("simulator N=64, 80×60, 10 objects + 3 NPC robots each", "env-steps/s",
         median3(bench_sim, int(150 * k), 64, 80, 60, loop_with_objects(), THREE_NPCS), None, 250),
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
    by = {name: value for name, _, value, _, _ in rows}
    for size, a, b in (("640×480", "simulator, 640×480, empty road", "simulator, 640×480, 10 objects + 3 NPC robots"),
                       ("N=64 80×60", "simulator N=64, 80×60, empty road",
                        "simulator N=64, 80×60, 10 objects + 3 NPC robots each")):
        print(f"cost of 10 objects + 3 NPC robots, {size}: {by[a] / by[b]:.2f}× the empty road (target ≤ 2×)")


if __name__ == "__main__":
    main()
