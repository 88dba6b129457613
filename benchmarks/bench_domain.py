"""Domain speed: the figures issues 2 and 16 set targets for, as tables.

    .venv/bin/python benchmarks/bench_domain.py              # full (a few minutes)
    .venv/bin/python benchmarks/bench_domain.py --quick      # fewer steps
    .venv/bin/python benchmarks/bench_domain.py --busy no    # skip the busy-neighbour table
    .venv/bin/python benchmarks/bench_domain.py --only fisheye   # the rows whose name has "fisheye"

Each figure is the median of 3 runs, driven by the privileged PID controller (as the gym-duckietown
reference figures were), after a warm-up that compiles the kernels. Targets (2 cores, no GPU, issue 16):
single env 640×480 without blur ≥ 1,000 steps/s, 160×120 ≥ 5,000 steps/s; N = 64 at 80×60 ≥ 50,000
env-steps/s; physics + lane pose without rendering ≥ 1,000,000 env-steps/s. With 10 map objects and 3 NPC
robots per episode the simulator may cost at most 2× the empty road (issue 8): the ``simulator, ...`` rows
measure both and the lines under the table print the ratio. ``gym.make_vec`` rows: Gymnasium's own sync
and async vector envs of 8 (async: one worker process per env, each on one thread). The ``fisheye`` rows
(no target, no reference figure) render through the renderer's general path, pixel by pixel, as a lens's
image rows are curves on the ground; at 160×120 they run on one thread, so a slowdown of the serial kernel
shows there (one took a blurred 160×120 fisheye frame from ~0.35 to ~1.7 ms).

The second table runs every figure beside a busy neighbour process (a pure-Python loop that keeps one core
busy) and, without it, with a PyTorch training step after every env step in the same process; each is
measured with the default threads and with ``numba.set_num_threads(1)``, alternating every twentieth of the
steps of one run (so that both see the same drifting load), and the default must
reach ≥ 90 % of one thread (issue 16: a parallel kernel must never lose to a serial one under contention).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import math
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable

import gymnasium as gym
import numba
import numpy as np
from rich.console import Console
from rich.table import Table

import proxybench  # noqa: F401  (registers the Gymnasium env)
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


def pid_action(lateral: float, heading: float) -> np.ndarray:
    """One robot's PWM from :func:`pid_actions`' control law, in Python floats: a NumPy call per step costs
    microseconds, as much as a fifth of a 160×120 env step, and the figure is meant to time the env."""
    lateral = lateral if math.isfinite(lateral) else 0.0  # the lane errors are finite or NaN (off the lanes)
    heading = heading if math.isfinite(heading) else 0.0
    return wheels_for(0.3, -(10.0 * lateral + 4.0 * heading))


def loop_with_objects() -> Map:
    """loop_3x3 with 10 objects along the roadsides (inside and outside the loop)."""
    kinds = ["duckie", "cone", "sign_stop", "duckiebot", "barrier", "duckie", "cone", "duckie", "sign_left", "duckie"]
    spots = [(0.65, 0.88), (1.1, 0.88), (0.88, 0.65), (0.88, 1.1), (0.03, 0.88), (1.72, 0.88), (0.88, 0.03),
             (0.88, 1.72), (0.1, 0.1), (1.65, 1.65)]
    objs = tuple(MapObject(k, x, y, heading=math.pi / 2 if k == "barrier" else 0.0) for k, (x, y) in zip(kinds, spots,
                                                                                                       strict=True))
    return dataclasses.replace(load_map("loop_3x3"), objects=objs)


class Clock:
    """Times the steps of a benchmark loop (``begin`` / ``end`` around each); ``rate`` gives units/s."""

    def __init__(self) -> None:
        self.elapsed = 0.0
        self.steps = 0

    def begin(self) -> None:
        self._t = time.perf_counter()

    def end(self) -> None:
        self.elapsed += time.perf_counter() - self._t
        self.steps += 1

    def rate(self, units_per_step: float) -> float:
        return units_per_step * self.steps / self.elapsed


class Alternating(Clock):
    """Switches between the default threads and ``numba.set_num_threads(1)`` every ``block`` steps of one
    loop, timing each: on a shared machine whose load drifts, both modes see the same load."""

    def __init__(self, block: int) -> None:
        super().__init__()
        self.block = max(1, block)
        self.threads = numba.get_num_threads()
        self.by_mode = {True: [0.0, 0], False: [0.0, 0]}
        self.mode = True
        self.skip = self.block

    def end(self) -> None:
        dt = time.perf_counter() - self._t
        if self.skip > 0:  # the first block warms up (first-call costs would fall on one mode)
            self.skip -= 1
            return
        slot = self.by_mode[self.mode]
        slot[0] += dt
        slot[1] += 1
        if slot[1] % self.block == 0:
            self.mode = not self.mode
            numba.set_num_threads(self.threads if self.mode else 1)

    def rate(self, units_per_step: float) -> tuple[float, float]:
        numba.set_num_threads(self.threads)
        (ta, na), (to, no) = self.by_mode[True], self.by_mode[False]
        return units_per_step * na / ta, units_per_step * no / to


def bench_single(steps: int, width: int, height: int, blur: float, map_: Map | str = "loop_3x3",
                 lens: str | None = None, clock: Clock | None = None) -> float:
    """Steps/s of one env; ``lens``: a fisheye lens model (its image rows are curves on the ground, which the
    renderer shades pixel by pixel), else the pinhole camera (rows are lines, shaded span by span)."""
    fisheye = {} if lens is None else {"fisheye": True, "lens_model": lens}
    env = LaneFollowingEnv(map_, params=DomainParams(image_width=width, image_height=height, blur_time=blur,
                                                     **fisheye))
    env.reset(seed=0)
    for _ in range(20):
        env.step(np.array([0.3, 0.3]))
    env.reset(seed=1)
    lp = env.sim.lane
    clock = clock or Clock()
    for _ in range(steps):
        clock.begin()
        a = pid_action(float(lp[0, LP.LATERAL]), float(lp[0, LP.HEADING_ERROR]))
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset()
        clock.end()
    return clock.rate(1)


def bench_vector(steps: int, n: int, width: int, height: int, blur: float, clock: Clock | None = None) -> float:
    env = LaneFollowingVectorEnv(num_envs=n, params=DomainParams(image_width=width, image_height=height,
                                                                 blur_time=blur))
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.full((n, 2), 0.3))
    lp = env.sim.lane
    clock = clock or Clock()
    for _ in range(steps):
        clock.begin()
        env.step(pid_actions(lp[:, LP.LATERAL], lp[:, LP.HEADING_ERROR]))
        clock.end()
    return clock.rate(n)


#: three NPC Duckiebots: one 0.6 m ahead in the robot's lane (in view), two anywhere on the lanes
THREE_NPCS = Traffic(robots=(NpcRobot(ahead=0.6), NpcRobot(), NpcRobot(driver="pure-pursuit")))


def bench_sim(steps: int, n: int, width: int, height: int, map_: Map | str = "loop_3x3",
              npcs: Traffic | None = None, clock: Clock | None = None) -> float:
    """Env-steps/s of the simulator itself (render + step, PD on the egos and the NPC robots), any world."""
    sim = Simulator(map_, DomainParams(image_width=width, image_height=height, blur_time=0.0), n=n, npcs=npcs)
    for i in range(n):
        sim.reset(i, seed=i)
    sim.render()
    clock = clock or Clock()
    for k in range(steps):
        if k % 150 == 149:  # fresh episodes now and then, as an env would after a crash; untimed: a reset of
            for i in range(n):  # 64 worlds with NPCs costs many steps, and whichever mode it fell in would pay
                sim.reset(i, seed=k + i)
        clock.begin()
        sim.render()
        npc = pid_actions(sim.npc_lane[:, LP.LATERAL], sim.npc_lane[:, LP.HEADING_ERROR]) if sim.worlds.k else None
        sim.step(pid_actions(sim.lane[:, LP.LATERAL], sim.lane[:, LP.HEADING_ERROR]), npc_commands=npc)
        clock.end()
    return clock.rate(n)


def bench_physics(steps: int, n: int, clock: Clock | None = None) -> float:
    sim = Simulator("loop_3x3", DomainParams(), n=n, render=False)
    sim.step(np.zeros((n, 2)))
    lp = sim.lane
    clock = clock or Clock()
    for _ in range(steps):
        clock.begin()
        sim.step(pid_actions(lp[:, LP.LATERAL], lp[:, LP.HEADING_ERROR]))
        clock.end()
    return clock.rate(n)


def bench_gym_vec(steps: int, n: int, width: int, height: int, mode: str, clock: Clock | None = None) -> float:
    """Env-steps/s of ``gym.make_vec(..., vectorization_mode=mode)`` (sync: one process; async: a worker each)."""
    env = gym.make_vec("proxybench/LaneFollowing-v0", num_envs=n, vectorization_mode=mode,
                       params={"image_width": width, "image_height": height, "blur_time": 0.0})
    try:
        _, info = env.reset(seed=0)
        for _ in range(5):
            _, _, _, _, info = env.step(np.full((n, 2), 0.3, dtype=np.float32))
        clock = clock or Clock()
        for _ in range(steps):
            clock.begin()
            lat = np.array([lp.lateral for lp in info["lane_pose"]])
            head = np.array([lp.heading_error for lp in info["lane_pose"]])
            _, _, _, _, info = env.step(pid_actions(lat, head).astype(np.float32))
            clock.end()
        return clock.rate(n)
    finally:
        env.close()


def bench_single_with_training(steps: int, width: int, height: int, clock: Clock | None = None) -> float:
    """Env steps/s (time in ``env.step`` only) of a single env when every step is followed by a PyTorch
    training step in the same process (a small CNN on the frame, PyTorch's default threads, whose OpenMP
    workers spin after each operation), as a learning agent's loop does."""
    import torch

    net = torch.nn.Sequential(torch.nn.Conv2d(3, 8, 5, stride=4), torch.nn.ReLU(), torch.nn.AdaptiveAvgPool2d(8),
                              torch.nn.Flatten(), torch.nn.Linear(512, 2))
    opt = torch.optim.SGD(net.parameters(), lr=1e-3)
    env = LaneFollowingEnv(params=DomainParams(image_width=width, image_height=height, blur_time=0.0))
    obs, _ = env.reset(seed=1)
    lp = env.sim.lane

    def train(frame: np.ndarray) -> None:
        x = torch.from_numpy(frame).permute(2, 0, 1)[None].float() / 255.0
        loss = net(x).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()

    for _ in range(10):
        obs, *_ = env.step(np.array([0.3, 0.3]))
        train(obs)
    env.reset(seed=1)
    clock = clock or Clock()
    for _ in range(steps):
        a = pid_action(float(lp[0, LP.LATERAL]), float(lp[0, LP.HEADING_ERROR]))
        clock.begin()
        obs, _, term, trunc, _ = env.step(a)
        clock.end()
        train(obs)
        if term or trunc:
            env.reset()
    return clock.rate(1)


def median3(fn, *args) -> float:
    return statistics.median(fn(*args) for _ in range(3))


@dataclasses.dataclass(frozen=True)
class Row:
    """One figure: ``fn(*args)`` → units per second, with its target and the gym-duckietown reference."""

    name: str
    unit: str
    fn: Callable[..., float]
    args: tuple
    target: float | None = None
    ref: float | None = None
    busy: bool = True  # also measured beside a busy neighbour


def rows(k: float) -> list[Row]:
    """Every figure of the table; ``k`` scales the step counts (0.1 for ``--quick``)."""
    def s(x: int) -> int:
        return max(3, int(x * k))

    objs = loop_with_objects()
    return [
        Row("single env, 640×480, no blur", "steps/s", bench_single, (s(1800), 640, 480, 0.0), 1_000, 50),
        Row("single env, 640×480, no blur, 10 objects", "steps/s", bench_single, (s(1800), 640, 480, 0.0, objs),
            None, 50),
        Row("single env, 640×480, blur 0.05 s ×3", "steps/s", bench_single, (s(900), 640, 480, 0.05), None, 50),
        Row("single env, 160×120, no blur", "steps/s", bench_single, (s(1800), 160, 120, 0.0), 5_000, 250),
        Row("single env, 160×120, fisheye, no blur", "steps/s", bench_single,
            (s(1800), 160, 120, 0.0, "loop_3x3", "plumb_bob")),
        Row("single env, 160×120, fisheye, blur 0.05 s ×3", "steps/s", bench_single,
            (s(900), 160, 120, 0.05, "loop_3x3", "plumb_bob")),
        Row("single env, 160×120, equidistant fisheye, no blur", "steps/s", bench_single,
            (s(1800), 160, 120, 0.0, "loop_3x3", "equidistant")),
        Row("single env, 640×480, fisheye, no blur", "steps/s", bench_single,
            (s(900), 640, 480, 0.0, "loop_3x3", "plumb_bob")),
        Row("batched N=64, 80×60, no blur", "env-steps/s", bench_vector, (s(300), 64, 80, 60, 0.0), 50_000, 250),
        Row("batched N=64, 80×60, blur 0.05 s ×3", "env-steps/s", bench_vector, (s(200), 64, 80, 60, 0.05), None,
            250),
        Row("simulator, 640×480, empty road", "steps/s", bench_sim, (s(900), 1, 640, 480), None, 50),
        Row("simulator, 640×480, 10 objects + 3 NPC robots", "steps/s", bench_sim,
            (s(900), 1, 640, 480, objs, THREE_NPCS), None, 50),
        Row("simulator N=64, 80×60, empty road", "env-steps/s", bench_sim, (s(150), 64, 80, 60), None, 250),
        Row("simulator N=64, 80×60, 10 objects + 3 NPC robots each", "env-steps/s", bench_sim,
            (s(150), 64, 80, 60, objs, THREE_NPCS), None, 250),
        Row("physics + lane pose, N=4096, no rendering", "env-steps/s", bench_physics, (s(300), 4096), 1_000_000,
            500),
        Row("gym.make_vec sync, 8 × 160×120", "env-steps/s", bench_gym_vec, (s(300), 8, 160, 120, "sync"), None,
            250),
        Row("gym.make_vec async, 8 × 160×120 (8 processes)", "env-steps/s", bench_gym_vec,
            (s(300), 8, 160, 120, "async"), None, 250, busy=False),
    ]


class BusyNeighbour:
    """Another process that keeps one core busy (a pure-Python loop), for as long as the ``with`` lasts."""

    def __enter__(self) -> BusyNeighbour:
        # the loop ends by itself when this process goes, even if killed before ``__exit__``
        loop = "import os\nparent = os.getppid()\nwhile os.getppid() == parent:\n    sum(range(100_000))\n"
        self.proc = subprocess.Popen([sys.executable, "-c", loop])
        time.sleep(0.3)
        return self

    def __exit__(self, *exc) -> None:
        self.proc.terminate()
        self.proc.wait()


def side_by_side(fn: Callable[..., float], args: tuple, name: str = "") -> tuple[float, float]:
    """(default threads, one thread) rates of ``fn(*args)``: one run whose steps alternate between the two
    in blocks of about a twentieth (printed as they come, since a loaded machine makes the table slow)."""
    auto, one = fn(*args, clock=Alternating(args[0] // 20))
    print(f"  {name}: default {auto:,.0f}, one thread {one:,.0f}", flush=True)
    return auto, one


def threading_layer() -> str:
    """Numba's threading layer, or "no" where no parallel kernel has run (rows that all ran on one thread)."""
    try:
        return numba.threading_layer()
    except ValueError:
        return "no"


def print_table(all_rows: list[Row], values: dict[str, float]) -> None:
    table = Table(title=f"proxybench domain speed — {os.cpu_count()} cores, numba {numba.__version__} "
                        f"({numba.config.NUMBA_NUM_THREADS} threads, {threading_layer()} layer)")
    for col in ("case", "unit", "proxybench", "target", "gym-duckietown ref", "× ref"):
        table.add_column(col, justify="left" if col == "case" else "right")
    for r in all_rows:
        value = values[r.name]
        ok = "" if r.target is None else (" ✓" if value >= r.target else " ✗")
        table.add_row(r.name, r.unit, f"{value:,.0f}", f"{r.target:,}{ok}" if r.target else "–",
                      f"{r.ref:,}" if r.ref else "–", f"{value / r.ref:,.0f}×" if r.ref else "–")
    Console(width=140).print(table)


def print_busy(results: list[tuple[str, str, str, float, float]]) -> None:
    table = Table(title="beside a busy neighbour: default threads vs the same code on one thread "
                        "(alternating blocks of steps in one run; target ≥ 90 %)")
    for col in ("case", "neighbour", "unit", "default", "one thread", "ratio"):
        table.add_column(col, justify="left" if col in ("case", "neighbour") else "right")
    for name, neighbour, unit, auto, one in results:
        ratio = auto / one
        table.add_row(name, neighbour, unit, f"{auto:,.0f}", f"{one:,.0f}",
                      f"{ratio:.0%}{' ✓' if ratio >= 0.9 else ' ✗'}")
    Console(width=140).print(table)


def torch_row_name(width: int, height: int) -> str:
    return f"single env, {width}×{height}, a PyTorch training step after each (env time)"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer steps (for smoke tests)")
    ap.add_argument("--scale", type=float, default=None, help="multiply every step count (default 1, --quick 0.1)")
    ap.add_argument("--busy", choices=("both", "no", "only"), default="both",
                    help="also measure beside a busy neighbour process (default), skip that, or only that")
    ap.add_argument("--only", metavar="TEXT", default="",
                    help="only the rows whose name contains TEXT (e.g. fisheye, 160×120, PyTorch)")
    args = ap.parse_args()
    k = args.scale or (0.1 if args.quick else 1.0)
    all_rows = [r for r in rows(k) if args.only in r.name]
    torch_sizes = [(w, h) for w, h in ((640, 480), (160, 120)) if args.only in torch_row_name(w, h)]
    if not all_rows and not torch_sizes:
        ap.error(f"--only {args.only!r}: no row's name contains it")
    if args.busy != "only":
        values = {r.name: median3(r.fn, *r.args) for r in all_rows}
        print_table(all_rows, values)
        by = values
        for size, a, b in (("640×480", "simulator, 640×480, empty road",
                            "simulator, 640×480, 10 objects + 3 NPC robots"),
                           ("N=64 80×60", "simulator N=64, 80×60, empty road",
                            "simulator N=64, 80×60, 10 objects + 3 NPC robots each")):
            if a not in by or b not in by:
                continue
            print(f"cost of 10 objects + 3 NPC robots, {size}: {by[a] / by[b]:.2f}× the empty road (target ≤ 2×)")
    if args.busy != "no":
        results = []
        with BusyNeighbour():
            for r in all_rows:
                if r.busy:
                    results.append((r.name, "1 busy process", r.unit, *side_by_side(r.fn, r.args, name=r.name)))
        if importlib.util.find_spec("torch") is not None:
            steps = max(10, int(300 * k))
            for w, h in torch_sizes:
                results.append((torch_row_name(w, h), "PyTorch, same process", "steps/s",
                                *side_by_side(bench_single_with_training, (steps, w, h), name=f"PyTorch {w}×{h}")))
        print_busy(results)


if __name__ == "__main__":
    main()
