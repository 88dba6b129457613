"""Protocol overhead per step: an agent served as a node and driven over the wire vs called in-process.

Per frame size (160×120, 640×480) it measures, medians over many steps:

- JPEG encode and decode alone (the codec cost both paths pay once per frame);
- in-process: ``jpeg.roundtrip(frame)`` + ``agent.act`` (what the runner does for a built-in agent);
- remote: ``AgentProcess.step(obs, jpeg=bytes)``, observations + get_commands written at once, with the
  JPEG already encoded (the node decodes it); the protocol overhead is this minus (decode + act);
- remote, two round trips (``observe`` then ``get_commands``), and a bare ``get_commands`` round trip, the
  figure to compare with the real zuper-nodes node (1.6-2.0 ms median).

``--codecs`` also compares Pillow, simplejpeg and PyTurboJPEG (when its system library is present).
Run: ``python benchmarks/bench_protocol.py [--quick] [--codecs]``.
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
from proxybench.protocol import AgentProcess, jpeg

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
    print("overhead = remote_step (JPEG pre-encoded, node decodes) - decode - act; target ≤ 1000 µs at 160x120")
    if args.codecs:
        print("\n| codec | frame | KB | encode µs | decode µs |\n|---|---|---|---|---|")
        for name, size, kb, enc, dec in codecs(n // 2):
            print(f"| {name} | {size} | {kb:.1f} | {enc:.0f} | {dec:.0f} |")


if __name__ == "__main__":
    main()
