"""SDK agents through the virtual DB21J: frame → command latency, achievable camera rate, simulated time per wall time.

For each frame size (160×120, 640×480) and each agent style (a camera callback that answers at once, and a
blocking ``capture(block=True); set_pwm()`` loop), one episode in lock-step (frames as fast as the agent
answers: the achievable camera rate) and one in real time (15 Hz, what SDK agents expect), first quiet,
then beside a busy neighbour (one ``while True: pass`` process at nice 0, killed at the end). Prints, per
run: median and 90th percentile of frame → command latency [ms] (publish of the frame in proxybench to the
command's arrival back in proxybench), frames per wall second, and simulated seconds per wall second of
the whole episode including the program's start.

    python benchmarks/bench_dtps.py [--quick] [--seconds 10]

Needs the SDK environment (``proxybench dtps setup``).
"""

from __future__ import annotations

import argparse
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

AGENTS = {
    "callback": """
from duckietown.sdk.robots.duckiebot import DB21J
import time
robot = DB21J("map_0/vehicle_0", simulated=True)
robot.motors.start()
robot.camera.attach(lambda image: robot.motors.set_pwm(0.2, 0.2))
robot.camera.start()
while True:
    time.sleep(1)
""",
    "blocking": """
from duckietown.sdk.robots.duckiebot import DB21J
robot = DB21J("map_0/vehicle_0", simulated=True)
robot.camera.start()
robot.motors.start()
while True:
    if robot.camera.capture(block=True) is not None:
        robot.motors.set_pwm(0.2, 0.2)
""",
}


def episode(folder: Path, style: str, size: tuple[int, int], timing: str, seconds: float) -> dict:
    plant = sim_plant("loop_3x3", DomainParams(image_width=size[0], image_height=size[1]))
    t0 = time.perf_counter()
    with SdkAgent(f"python3 {style}.py", options=SdkOptions(timing=timing, cwd=str(folder))) as agent:
        traj = rollout(plant, AgentPolicy([agent]), [1], seconds)[0]
        stats = agent.stats()
    wall = time.perf_counter() - t0
    frames = stats["frames_answered"] + 1
    return {"frames_per_s": frames / max(1e-9, wall - stats["start_s"]), "sim_per_wall": traj.duration / wall,
            "start_s": stats["start_s"], **stats, "end": traj.termination}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="160×120 only, callback agent only, 4 s episodes")
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    seconds = 4.0 if args.quick else args.seconds
    sizes = [(160, 120)] if args.quick else [(160, 120), (640, 480)]
    styles = ["callback"] if args.quick else ["callback", "blocking"]
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        for style, code in AGENTS.items():
            (folder / f"{style}.py").write_text(code)
        episode(folder, "callback", (160, 120), "lockstep", 1.0)  # warm-up: compiled kernels, caches
        for load in ("quiet", "busy neighbour"):
            hog = None
            if load != "quiet":
                hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
            try:
                for size in sizes:
                    for style in styles:
                        for timing in ("lockstep", "realtime"):
                            r = episode(folder, style, size, timing, seconds)
                            print(f"{load:15s} {size[0]}x{size[1]} {style:8s} {timing:8s}: latency median "
                                  f"{r['latency_median_ms']:6.1f} ms p90 {r['latency_p90_ms']:6.1f} ms, "
                                  f"{r['frames_per_s']:6.1f} frames/s, sim/wall {r['sim_per_wall']:.2f} "
                                  f"(start {r['start_s']:.1f} s), late frames {r['late_frames']}, end {r['end']}",
                                  flush=True)
            finally:
                if hog is not None:
                    hog.kill()
                    hog.wait()


if __name__ == "__main__":
    main()
