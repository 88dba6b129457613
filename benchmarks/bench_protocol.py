"""Protocol overhead per step: an agent served as a node and driven over the wire vs called in-process.

Per frame size (160×120, 640×480) it measures, medians over many steps:

- JPEG encode and decode alone (the codec cost both paths pay once per frame);
- in-process: ``jpeg.roundtrip(frame)`` + ``agent.act`` (what the runner does for a built-in agent);
- remote: ``AgentProcess.step(obs, jpeg=bytes)``, observations + get_commands written at once, with the
  JPEG already encoded (the node decodes it); the protocol overhead is this minus (decode + act);
- remote, two round trips (``observe`` then ``get_commands``), and a bare ``get_commands`` round trip, the
  figure to compare with the real zuper-nodes node (1.6-2.0 ms median).

``--codecs`` also compares Pillow, simplejpeg and PyTurboJPEG (when its system library is present).

``--robot`` measures the robot protocol: one control period of a camera agent on the simulator served as a
robot node (``proxybench robot serve``; set_robot_commands + step + get_sim_state + get_robot_state with
the tick trace + get_robot_observations in one write, then the caller decodes the JPEG and the agent acts)
against the same period in-process (render, JPEG round trip, act, physics); the difference is the robot
protocol's overhead per frame. Also a bare ``get_sim_state`` round trip.
Run: ``python benchmarks/bench_protocol.py [--quick] [--codecs] [--robot]``.
"""

from __future__ import annotations

import argparse
import io
import os
import statistics
import sys
import time
from collections.abc import Callable

import numpy as np

from proxybench.agents.base import Observation
from proxybench.agents.zoo import make_agent
from proxybench.protocol import AgentProcess, RemoteRobot, jpeg

AGENT = "straight"  # trivial act(): what is left is the protocol


def frames(width: int, height: int, n: int = 8) -> list[np.ndarray]:
    """Rendered camera frames (realistic JPEG sizes); noise + gradient if the renderer is unavailable."""
    try:
        from proxybench.domain.env import LaneFollowingEnv

        env = LaneFollowingEnv(params={"image_width": width, "image_height": height})
        env.reset(seed=1)
        return [env.step([0.3, 0.32])[0].copy() for _ in range(n)]
    except Exception:  # pragma: no cover - fallback for a broken renderer
        rng = np.random.default_rng(0)
        ramp = np.linspace(0, 200, width, dtype=np.float32)[None, :, None]
        return [np.clip(ramp + rng.normal(0, 20, (height, width, 3)), 0, 255).astype(np.uint8) for _ in range(n)]


def median_us(fn: Callable[[int], object], n: int) -> float:
    for i in range(min(20, n)):
        fn(i)
    times = []
    for i in range(n):
        t0 = time.perf_counter()
        fn(i)
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1e6


def measure(width: int, height: int, n: int) -> dict[str, float]:
    imgs = frames(width, height)
    jpgs = [jpeg.encode(f) for f in imgs]
    agent = make_agent(AGENT)
    agent.reset(0)
    r: dict[str, float] = {"jpeg_kb": statistics.mean(len(j) for j in jpgs) / 1024}
    r["encode"] = median_us(lambda i: jpeg.encode(imgs[i % len(imgs)]), n)
    r["decode"] = median_us(lambda i: jpeg.decode(jpgs[i % len(jpgs)]), n)
    r["act"] = median_us(lambda i: agent.act(Observation(imgs[0], i * 0.05, (0.0, 0.0), 0.01)), n)
    r["in_process"] = median_us(
        lambda i: agent.act(Observation(jpeg.roundtrip(imgs[i % len(imgs)]), i * 0.05, (0.0, 0.0), 0.01)), n)
    with AgentProcess([sys.executable, "-m", "proxybench.protocol", AGENT]) as proc:
        proc.seed(0)
        proc.episode_start("bench")

        def obs(i: int) -> Observation:
            return Observation(imgs[i % len(imgs)], i * 0.05, (0.0, 0.0), 0.01)

        r["remote_step"] = median_us(lambda i: proc.step(obs(i), jpgs[i % len(jpgs)]), n)
        r["remote_two_trips"] = median_us(
            lambda i: (proc.observe(obs(i), jpgs[i % len(jpgs)]), proc.get_commands(i * 0.05)), n)
        r["get_commands"] = median_us(lambda i: proc.get_commands(i * 0.05), n)
    r["overhead"] = r["remote_step"] - r["decode"] - r["act"]
    return r


def measure_robot(width: int, height: int, n: int) -> dict[str, float]:
    """Per-frame µs of a camera agent driving the simulator in-process and through the robot protocol."""
    from proxybench.domain.dynamics import TRACE_FIELDS
    from proxybench.domain.maps import load_map
    from proxybench.domain.params import DomainParams
    from proxybench.domain.simulator import Simulator

    params = DomainParams(image_width=width, image_height=height)
    sim = Simulator("loop_3x3", params)
    sim.reset(0, 1)
    trace = np.zeros((1, sim.substeps, len(TRACE_FIELDS)))
    agent = make_agent(AGENT)
    agent.reset(0)
    still = np.zeros((1, 2))  # the robot stands still: the episode never ends, rendering costs the same
    r: dict[str, float] = {}

    def in_process(i: int) -> None:
        image = jpeg.roundtrip(sim.render()[0])
        agent.act(Observation(image, float(sim.time[0]), (0.0, 0.0), 0.01))
        sim.step(still, trace)

    r["render"] = median_us(lambda i: sim.render(), n)
    cmd = [sys.executable, "-m", "proxybench.cli", "robot", "serve", "--param", f"image_width={width}",
           "--param", f"image_height={height}"]
    with RemoteRobot(cmd, init_timeout=120) as robot:
        robot.start_episode(load_map("loop_3x3"), 1)
        robot.state(0.0)
        now = {"k": 0, "obs": robot.observations(0.0)}
        dt = 1.0 / params.frame_rate

        def remote(i: int) -> None:
            k, o = now["k"], now["obs"].observations
            agent.act(Observation(jpeg.decode_received(o.jpg), o.timestamp, o.odometry, o.resolution))
            _, _, now["obs"] = robot.frame(k * dt, still[0], (k + 1) * dt)
            now["k"] = k + 1

        # interleaved, so that both paths meet the same load from other processes
        times: dict[str, list[float]] = {"in_process_frame": [], "robot_frame": []}
        for i in range(n + 20):
            for key, fn in (("in_process_frame", in_process), ("robot_frame", remote)):
                t0 = time.perf_counter()
                fn(i)
                if i >= 20:
                    times[key].append(time.perf_counter() - t0)
        r.update({k: statistics.median(v) * 1e6 for k, v in times.items()})
        r["get_sim_state"] = median_us(lambda i: robot.process.get_sim_state(), n)
    r["overhead"] = r["robot_frame"] - r["in_process_frame"]
    return r


def codecs(n: int) -> list[tuple[str, str, float, float, float]]:
    """(codec, size, KB, encode µs, decode µs) at quality 75, 4:2:0."""
    rows = []
    try:
        import turbojpeg

        tj = turbojpeg.TurboJPEG()
    except Exception:
        tj = None
    import simplejpeg
    from PIL import Image

    def pil_enc(f: np.ndarray) -> bytes:
        b = io.BytesIO()
        Image.fromarray(f).save(b, format="JPEG", quality=75)
        return b.getvalue()

    impls: dict[str, tuple[Callable, Callable]] = {
        "Pillow": (pil_enc, lambda b: np.asarray(Image.open(io.BytesIO(b)).convert("RGB"))),
        "simplejpeg": (lambda f: simplejpeg.encode_jpeg(f, 75, "RGB", "420"),
                       lambda b: simplejpeg.decode_jpeg(b, "RGB", False, False)),
    }
    if tj is not None:
        impls["PyTurboJPEG"] = (lambda f: tj.encode(f, 75, turbojpeg.TJPF_RGB, turbojpeg.TJSAMP_420),
                                lambda b: tj.decode(b, turbojpeg.TJPF_RGB))
    for w, h in ((160, 120), (640, 480)):
        f = np.ascontiguousarray(frames(w, h, 2)[1])
        for name, (enc, dec) in impls.items():
            data = enc(f)
            rows.append((name, f"{w}x{h}", len(data) / 1024, median_us(lambda i, f=f, enc=enc: enc(f), n),
                         median_us(lambda i, d=data, dec=dec: dec(d), n)))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer steps (a few seconds)")
    parser.add_argument("--codecs", action="store_true", help="also compare JPEG codecs")
    parser.add_argument("--robot", action="store_true", help="also measure the robot protocol per frame")
    args = parser.parse_args()
    n = 200 if args.quick else 2000
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"# bench_protocol: {cores} cores, python {sys.version.split()[0]}, agent {AGENT!r}, "
          f"{n} steps per figure, medians in µs")
    cols = ["jpeg_kb", "encode", "decode", "act", "in_process", "remote_step", "overhead", "remote_two_trips",
            "get_commands"]
    print("| frame | " + " | ".join(cols) + " |")
    print("|---" * (len(cols) + 1) + "|")
    for w, h in ((160, 120), (640, 480)):
        r = measure(w, h, n)
        print(f"| {w}x{h} | " + " | ".join(f"{r[c]:.1f}" for c in cols) + " |")
    print("overhead = remote_step (JPEG pre-encoded, node decodes) - decode - act; target ≤ 200 µs at 160x120 "
          "(issue 16; the real zuper-nodes node: 600-650 µs for get_commands alone)")
    if args.robot:
        cols = ["render", "in_process_frame", "robot_frame", "overhead", "get_sim_state"]
        print("\n| frame | " + " | ".join(cols) + " |")
        print("|---" * (len(cols) + 1) + "|")
        for w, h in ((160, 120), (640, 480)):
            r = measure_robot(w, h, n // 2)
            print(f"| {w}x{h} | " + " | ".join(f"{r[c]:.0f}" for c in cols) + " |")
        print("overhead = robot_frame (one pipelined exchange + decode + act) - in_process_frame "
              "(render + JPEG round trip + act + physics)")
    if args.codecs:
        print("\n| codec | frame | KB | encode µs | decode µs |\n|---|---|---|---|---|")
        for name, size, kb, enc, dec in codecs(n // 2):
            print(f"| {name} | {size} | {kb:.1f} | {enc:.0f} | {dec:.0f} |")


if __name__ == "__main__":
    main()
