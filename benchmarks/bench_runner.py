"""Runner throughput on the thesis' predictivity workload slice.

    .venv/bin/python benchmarks/bench_runner.py            # 12 agents × 10 episodes × 60 s (a few minutes)
    .venv/bin/python benchmarks/bench_runner.py --quick    # 12 agents × 2 episodes × 10 s

Runs the agents on the 3×3 loop at 160×120 through the local process pool (one worker per core) into
a fresh run directory, and reports episodes per minute, simulated minutes per wall-clock minute per
core (issue 16's target: ≥ 120 for camera-based agents) and where the time goes: simulation (physics, lane
pose, rendering, the JPEG round trip of camera frames), agents, and bookkeeping (trajectories, metrics,
files, process pool). On a busy machine the wall figures fall with the load; the "sim-min / CPU-min"
column (simulated minutes per CPU minute of the workers) does much less, so compare variants by it there.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

from rich.console import Console
from rich.table import Table

from proxybench.agents import ZOO
from proxybench.domain.params import DomainParams
from proxybench.runner.backends import make_backend
from proxybench.runner.jobs import AgentSpec, DomainSpec, Job
from proxybench.runner.sweep import run_jobs

AGENTS = ["random", "straight", "bang-bang", "pid", "pid-fast", "pid-sluggish", "pure-pursuit", "vision",
          "vision-fast", "vision-slow", "vision-pitch15", "vision-wide"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--workers", type=int, default=os.cpu_count())
    ap.add_argument("--batch-size", type=int, default=8, help="robots per batched simulator (1: no batching)")
    args = ap.parse_args()
    episodes, seconds = (2, 10.0) if args.quick else (10, 60.0)
    dom = DomainSpec("default-160x120", DomainParams(image_width=160, image_height=120))
    jobs = [Job(AgentSpec(a), dom, "loop_3x3", e, 1000 + e, seconds) for a in AGENTS for e in range(episodes)]
    backend = make_backend("local", args.workers)
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        res = run_jobs(jobs, tmp, backend, batch_size=args.batch_size)
        wall = time.perf_counter() - t0
    backend.close()
    cores = backend.workers
    table = Table(title=f"runner: {len(AGENTS)} agents × {episodes} episodes × {seconds:g} s, 160×120, loop_3x3 — "
                        f"{os.cpu_count()} cores, {cores} workers")
    for col in ("group", "episodes", "simulated min", "episodes/min", "sim-min / wall-min / core",
                "sim-min / CPU-min", "sim %", "agent %", "bookkeeping %"):
        table.add_column(col, justify="right" if col != "group" else "left")
    groups = {"camera-based": [r for r in res.results if not ZOO[r.agent].privileged],
              "privileged": [r for r in res.results if ZOO[r.agent].privileged], "all": res.results}
    for name, rs in groups.items():
        sim_min = sum(r.timings["simulated_s"] for r in rs) / 60
        busy = {k: sum(r.timings[k] for r in rs) for k in ("sim_s", "agent_s", "bookkeeping_s", "setup_s")}
        total = sum(busy.values()) or 1.0
        # wall share of this group: its busy time over all busy time, times the wall clock
        all_busy = sum(sum(r.timings[k] for k in busy) for r in res.results) or 1.0
        wall_g = wall * total / all_busy
        cpu_min = sum(r.timings.get("cpu_s", float("nan")) for r in rs) / 60
        table.add_row(name, str(len(rs)), f"{sim_min:.1f}", f"{len(rs) / (wall_g / 60):.0f}",
                      f"{sim_min / (wall_g / 60) / cores:.0f}", f"{sim_min / cpu_min:.0f}",
                      f"{100 * busy['sim_s'] / total:.0f}",
                      f"{100 * busy['agent_s'] / total:.0f}",
                      f"{100 * (busy['bookkeeping_s'] + busy['setup_s']) / total:.0f}")
    Console(width=140).print(table)
    print(f"wall {wall:.1f} s for {len(jobs)} episodes ({len(jobs) / (wall / 60):.0f} episodes/min overall); "
          f"target (issue 16): camera-based ≥ 120 sim-min / wall-min / core on a quiet machine; "
          f"load average now {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")


if __name__ == "__main__":
    main()
