"""SDK agents through the virtual DB21J: frame → command latency, achievable camera rate, simulated time per wall time.

For each frame size (160×120, 640×480) and each agent style (the tests' lane follower as a camera callback,
and as a blocking ``capture(block=True); set_pwm()`` loop), one episode in lock-step (frames as fast as the agent
answers: the achievable camera rate) and one in real time (15 Hz, what SDK agents expect), first quiet,
then beside a busy neighbour (one busy-looping Python process at the benchmark's own niceness, which ends by
itself after ``--hog-seconds`` and is killed at the end). Prints, per
run: median and 90th percentile of frame → command latency [ms] (publish of the frame in proxybench to the
command's arrival back in proxybench), frames per wall second and simulated seconds per wall second while
driving (from the program's first command), and simulated seconds per wall second of the whole episode (the
bridge's and the program's starts included).

    python benchmarks/bench_dtps.py [--quick] [--seconds 10]

Needs the SDK environment (``proxybench dtps setup``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from proxybench.domain.params import DomainParams
from proxybench.dtps.agent import SdkAgent
from proxybench.dtps.options import SdkOptions
from proxybench.runner.episode import sim_plant
from proxybench.runner.rollout import AgentPolicy, rollout

_STEER = """
import numpy as np


def steer(bgr):
    h, w = bgr.shape[:2]
    low = bgr[h // 2:].astype(np.int16)
    yellow = (low[..., 2] > 150) & (low[..., 1] > 120) & (low[..., 0] < 100)
    white = low.min(axis=2) > 170
    xs_y, xs_w = np.nonzero(yellow)[1], np.nonzero(white)[1]
    centre = w / 2
    if xs_y.size and xs_w.size:
        centre = (xs_y.mean() + xs_w.mean()) / 2
    elif xs_y.size:
        centre = xs_y.mean() + 0.3 * w
    elif xs_w.size:
        centre = xs_w.mean() - 0.3 * w
    err = (centre - w / 2) / (w / 2)
    return 0.25 + 0.15 * err, 0.25 - 0.15 * err
"""

#: two styles of the tests' lane follower (tests/dtps_agents/lane.py), so that episodes last their length
AGENTS = {
    "callback": _STEER + """
import time
from duckietown.sdk.robots.duckiebot import DB21J
robot = DB21J("map_0/vehicle_0", simulated=True)
robot.motors.start()
robot.camera.attach(lambda image: robot.motors.set_pwm(*steer(image)))
robot.camera.start()
while True:
    time.sleep(1)
""",
    "blocking": _STEER + """
from duckietown.sdk.robots.duckiebot import DB21J
robot = DB21J("map_0/vehicle_0", simulated=True)
robot.camera.start()
robot.motors.start()
while True:
    bgr = robot.camera.capture(block=True)
    if bgr is not None:
        robot.motors.set_pwm(*steer(bgr))
""",
}


def episode(folder: Path, style: str, size: tuple[int, int], timing: str, seconds: float) -> dict:
    """One episode; rates over the episode itself (from the program's first command to its last frame), and over
    the whole of it (the virtual robot's and the program's starts included)."""
    plant = sim_plant("loop_3x3", DomainParams(image_width=size[0], image_height=size[1]))
    with SdkAgent(f"python3 {style}.py", options=SdkOptions(timing=timing, cwd=str(folder))) as agent:
        t0 = time.monotonic()
        traj = rollout(plant, AgentPolicy([agent]), [3], seconds)[0]
        end = time.monotonic()
        stats = agent.stats()
        wall = end - t0  # the bridge's and the program's starts included
        driving = max(1e-9, end - agent.t0)  # from the program's first command (the episode's wall zero)
    return {"frames_per_s": (stats["frames_answered"] + 1) / driving, "sim_per_wall": traj.duration / driving,
            "sim_per_wall_with_start": traj.duration / wall, **stats, "end": traj.termination,
            "sim_s": traj.duration}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="160×120 only, callback agent only, 4 s episodes")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--hog-seconds", type=float, default=900.0, help="the busy neighbour's longest life")
    args = ap.parse_args()
    seconds = 4.0 if args.quick else args.seconds
    sizes = [(160, 120)] if args.quick else [(160, 120), (640, 480)]
    styles = ["callback"] if args.quick else ["callback", "blocking"]
    print(f"load average before: {' '.join(f'{v:.1f}' for v in os.getloadavg())}; {os.cpu_count()} CPUs", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for style, code in AGENTS.items():
            (folder / f"{style}.py").write_text(code)
        episode(folder, "callback", (160, 120), "lockstep", 1.0)  # warm-up: compiled kernels, caches
        for load in ("quiet", "busy neighbour"):
            hog = None
            if load != "quiet":
                hog = subprocess.Popen([sys.executable, "-c", f"import time\nt = time.time() + {args.hog_seconds}\n"
                                        "while time.time() < t: pass"])
            try:
                for size in sizes:
                    for style in styles:
                        for timing in ("lockstep", "realtime"):
                            r = episode(folder, style, size, timing, seconds)
                            print(f"{load:15s} {size[0]}x{size[1]} {style:8s} {timing:8s}: latency median "
                                  f"{r['latency_median_ms']:6.1f} ms p90 {r['latency_p90_ms']:6.1f} ms, "
                                  f"{r['frames_per_s']:5.1f} frames/s, sim/wall {r['sim_per_wall']:.2f} driving, "
                                  f"{r['sim_per_wall_with_start']:.2f} with the starts (program {r['start_s']:.1f} s), "
                                  f"{r['sim_s']:.1f} s simulated, late frames {r['late_frames']}, end {r['end']}",
                                  flush=True)
                print(f"load average: {' '.join(f'{v:.1f}' for v in os.getloadavg())}", flush=True)
            finally:
                if hog is not None:
                    hog.kill()
                    hog.wait()


if __name__ == "__main__":
    main()
