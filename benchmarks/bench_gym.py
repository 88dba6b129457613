"""Steps per second of gym-duckietown behind the robot protocol against gym-duckietown alone.

Gym alone: ``Simulator.step`` (physics, render of the camera frame, gym's done check) in gym's own interpreter, nothing
else, as the node runs gym (pyglet's GL error checks off, one BLAS thread, Mesa's rasteriser in gym's thread;
``--gym-defaults`` runs it as gym does by default), from the same start pose and seed with the same command as
the node (gym's ``_valid_pose`` formats its debug lines even when they are not logged: an off-road frame costs
~2 ms more, so both must drive alike). The node: one robot-protocol frame driven by the caller (commands,
step, sim state, robot state, observations: gym's physics and render in the bridge, the frame through a
shared file, JPEG encoded and sent), camera on. Both at the same camera size, domain randomisation on (gym's
default), blocks of frames interleaved so that both meet the same load on a shared machine (``--blocks``
rounds: a gym block, then a block of each node, after ``--warmup`` untimed rounds, so that one-off costs, such
as a first episode's loading, count in neither; their figures are printed apart); steps/s over all blocks, and
the overhead with a 95 % bootstrap interval over rounds. Short blocks, many rounds (the defaults: 150 rounds
of 30 frames, ~1 s a round): a shared host's speed swings by a third within seconds, which 300-frame blocks
(~1.5 s each) pair badly, so the same code read +7 % and +21 % an hour apart; with 30 frames the robot also
stays on the road (it leaves it at frame 79). Also the CPU ms per step of every process involved (gym alone:
its one process; the node: caller, node and gym child), which a loaded machine disturbs less. ``--variant
NAME=SRC`` adds the node of another source tree (e.g. a worktree of the commit before a change), timed in the
same rounds. Needs ``proxybench gym setup``.

    python benchmarks/bench_gym.py [--frames 30] [--blocks 150] [--warmup 3] [--size 160x120] [--pin]
                                   [--variant before=../old/src]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time

import numpy as np
import psutil

from proxybench.domain.maps import load_map
from proxybench.gym.backend import bridge_environment
from proxybench.gym.environment import check_environment
from proxybench.protocol import RemoteRobot
from proxybench.runner.starts import start_poses

_ALONE = """
import json, sys, time
import numpy as np, pyglet
pyglet.options["headless"] = True
pyglet.options["debug_gl"] = DEBUG_GL
import logging; logging.disable(logging.CRITICAL)
from gym_duckietown.simulator import Simulator, geometry
from duckietown_world.world_duckietown.pwm_dynamics import get_DB18_nominal
w, h, frames, blocks = map(int, sys.argv[1:5])
x, y, th = map(float, sys.argv[5:8])
env = Simulator(map_name="small_loop", camera_width=w, camera_height=h, max_steps=10**9)
print("ready", flush=True)
for _ in range(blocks):
    sys.stdin.readline()
    env.seed(3)
    env.reset()
    pos, env.cur_angle = env.weird_from_cartesian(geometry.SE2_from_translation_angle([x, y], th))
    env.cur_pos = np.asarray(pos, dtype=float)
    q = env.cartesian_from_weird(env.cur_pos, env.cur_angle)
    env.state = get_DB18_nominal(delay=0.15).initialize(c0=(q, geometry.se2_from_linear_angular([0, 0], 0)), t0=0)
    action, t0, c0 = np.array(COMMAND), time.perf_counter(), time.process_time()
    for _ in range(frames):
        done = env.step(action)[2]
        action = np.zeros(2) if done else action  # as the node: a finished robot stops
    print("rate", frames / (time.perf_counter() - t0), 1e3 * (time.process_time() - c0) / frames, flush=True)
"""
#: the wheel command both hold: a wide left arc that stays in the loop's lane for a while
COMMAND = (0.3, 0.32)


def _cpu(procs: list[psutil.Process]) -> list[float]:
    """CPU seconds (user + system) so far of this process (the caller) and of each of ``procs``."""
    return [time.process_time(), *(sum(p.cpu_times()[:2]) for p in procs)]


def _node_block(robot: RemoteRobot, m, pose, frames: int) -> tuple[float, list[float]]:
    """Steps/s of one block of ``frames`` robot-protocol frames, and CPU ms per step of caller, node, gym child."""
    info = robot.start_episode(m, 3, pose=pose, seconds=frames / 30 + 1, camera=True)
    dt = 1 / info.frame_rate
    procs = [psutil.Process(robot.process.pid)]
    procs += procs[0].children(recursive=True)  # the node and its gym child
    c0, t0 = _cpu(procs), time.perf_counter()
    for k in range(frames):
        robot.frame(k * dt, np.array(COMMAND), (k + 1) * dt, observe=True)
    rate = frames / (time.perf_counter() - t0)
    return rate, [1e3 * (b - a) / frames for a, b in zip(c0, _cpu(procs), strict=True)]


def _overhead(gym: list[float], node: list[float], seed: int = 0) -> tuple[float, list[float]]:
    """Overhead in % of the node's steps/s over all its blocks against gym's over all of its blocks (each rate
    the frames over the summed block times), with a 95 % percentile-bootstrap interval that resamples rounds
    (a gym block and the node blocks beside it together)."""
    g, n = 1 / np.asarray(gym), 1 / np.asarray(node)  # seconds a frame: equal frames per block, so they add
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(g), size=(4000, len(g)))
    boot = 100 * (n[idx].sum(axis=1) / g[idx].sum(axis=1) - 1)
    low, high = np.percentile(boot, [2.5, 97.5])
    return round(float(100 * (n.sum() / g.sum() - 1)), 1), [round(float(low), 1), round(float(high), 1)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30, help="frames a block (default 30)")
    ap.add_argument("--blocks", type=int, default=150, help="timed rounds (default 150)")
    ap.add_argument("--warmup", type=int, default=3, help="untimed rounds first (default 3)")
    ap.add_argument("--size", default="160x120")
    ap.add_argument("--gym-defaults", action="store_true",
                    help="gym alone as gym runs by default: pyglet's GL error checks on, the inherited environment "
                         "(Mesa's and OpenBLAS's thread pools), where the node turns those off")
    ap.add_argument("--pin", action="store_true",
                    help="also time 'node-pinned' (`gym serve --cpus LAST`: gym's process on the last CPU, the node "
                         "on the others), blocks interleaved")
    ap.add_argument("--variant", action="append", default=[], metavar="NAME=SRC",
                    help="also time the node of another source tree (its src/ folder), blocks interleaved")
    args = ap.parse_args()
    w, h = (int(v) for v in args.size.split("x"))
    env = check_environment(render=False)
    if not env.ok:
        sys.exit("gym-duckietown's environment is not ready: " + "; ".join(env.problems))
    m = load_map("loop_3x3")
    pose = start_poses("loop_3x3", [3])[0]
    script = _ALONE.replace("COMMAND", repr(list(COMMAND))).replace("DEBUG_GL", str(args.gym_defaults))
    alone = subprocess.Popen([str(env.python), "-c", script, str(w), str(h), str(args.frames),
                              str(args.warmup + args.blocks),
                              *map(str, pose)], env=None if args.gym_defaults else bridge_environment(),
                             stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    while alone.stdout.readline().strip() != "ready":  # gym prints notices of its own first
        pass
    cmd = [sys.executable, "-m", "proxybench.cli", "gym", "serve", "--param", f"camera_width={w}",
           "--param", f"camera_height={h}"]
    variants = {"node": None, **dict(v.split("=", 1) for v in args.variant)}
    if args.pin:
        variants["node-pinned"] = None
    pinned = ["--cpus", str(max(psutil.Process().cpu_affinity()))]
    robots = {name: RemoteRobot(cmd + pinned if name == "node-pinned" else cmd, init_timeout=300, step_timeout=60,
                                env={"PYTHONPATH": src} if src else None) for name, src in variants.items()}
    gym_rates, gym_cpu = [], []
    rates: dict[str, list[float]] = {name: [] for name in variants}
    parts: dict[str, list[list[float]]] = {name: [] for name in variants}
    try:
        for _ in range(args.warmup + args.blocks):
            alone.stdin.write("go\n")
            alone.stdin.flush()
            line = alone.stdout.readline()
            while not line.startswith("rate "):
                line = alone.stdout.readline()
            gym_rates.append(float(line.split()[1]))
            gym_cpu.append(float(line.split()[2]))
            for name, robot in robots.items():
                rate, used = _node_block(robot, m, pose, args.frames)
                rates[name].append(rate)
                parts[name].append(used)
    finally:
        for robot in robots.values():
            robot.close()
    alone.wait()
    if args.warmup:  # the untimed rounds' figures, kept apart
        first = {"gym": gym_rates[:args.warmup], **{name: rates[name][:args.warmup] for name in variants}}
        gym_rates, gym_cpu = gym_rates[args.warmup:], gym_cpu[args.warmup:]
        rates = {name: r[args.warmup:] for name, r in rates.items()}
        parts = {name: p[args.warmup:] for name, p in parts.items()}
    out = {"size": args.size, "frames_per_block": args.frames, "rounds": args.blocks,
           "gym_alone_steps_per_s": round(len(gym_rates) / sum(1 / r for r in gym_rates), 1),
           "cpu_ms_per_step_gym_alone": round(statistics.median(gym_cpu), 2),
           "gym_blocks": [round(r, 1) for r in gym_rates],
           "warmup_steps_per_s": {k: [round(r, 1) for r in v] for k, v in first.items()} if args.warmup else None}
    for name in variants:
        overhead, interval = _overhead(gym_rates, rates[name])
        out[name] = {"steps_per_s": round(len(rates[name]) / sum(1 / r for r in rates[name]), 1),
                     "overhead_percent": overhead, "overhead_percent_95ci": interval,
                     "cpu_ms_per_step_caller_node_gym_child": [round(statistics.median(c), 2)
                                                               for c in zip(*parts[name], strict=True)],
                     "blocks": [round(r, 1) for r in rates[name]]}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
