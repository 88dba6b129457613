"""What container-image agents cost: the first unpack of a ~300 MB image, and an episode's start from the cache.

- **unpack**: an image of ~300 MB (the tests' Debian root file system with its own Python, ~50 MB, plus a layer of
  250 files of 1 MiB of random bytes, as compiled libraries and weights are: they barely compress) is unpacked into
  an empty cache, once as ``docker save`` writes it (plain layers) and once as an OCI layout (gzip layers);
- **start**: the same agent node (``tests/image_agents/z2_agent.py``, cbor2 only) started to the end of the
  protocol handshake, alternately from the cached image (its own ``/usr/bin/python3``) and as a package (this
  interpreter, the package folder at ``/agent``), both in the evaluator's sandbox; medians over ``--starts``.

Needs root (the safe sandbox), skopeo, umoci and mmdebstrap. Run: ``python benchmarks/bench_images.py [--quick]``.
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from proxybench.evaluator.image_agent import image_spec
from proxybench.evaluator.images import unpack_image
from proxybench.evaluator.sandbox import Limits, confine, detect_isolation
from proxybench.protocol import AgentProcess
from support.images import agent_image

AGENT = Path(__file__).resolve().parents[1] / "tests" / "image_agents" / "z2_agent.py"


def big_image(root: Path, megabytes: int) -> tuple[Path, Path]:
    """(OCI layout, docker archive) of the agent image plus ``megabytes`` files of random bytes."""
    layout = agent_image(root / "layout", AGENT)
    payload = root / "payload"
    payload.mkdir()
    for i in range(megabytes):
        (payload / f"blob{i:04d}.bin").write_bytes(os.urandom(1 << 20))
    subprocess.run(["umoci", "insert", "--rootless", "--image", f"{layout}:latest", str(payload), "/opt/weights"],
                   check=True, capture_output=True)
    subprocess.run(["umoci", "gc", "--layout", str(layout)], check=True)
    archive = root / "docker.tar"
    subprocess.run(["skopeo", "--insecure-policy", "copy", "-q", f"oci:{layout}:latest",
                    f"docker-archive:{archive}:agent:latest"], check=True)
    return layout, archive


def start_s(command: str) -> float:
    t0 = time.perf_counter()
    with AgentProcess(shlex.split(command), init_timeout=60) as proc:
        proc.seed(0)
        proc.episode_start("bench")
        return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="a 60 MB payload and 3 starts")
    ap.add_argument("--starts", type=int, default=9)
    args = ap.parse_args()
    megabytes, starts = (10, 3) if args.quick else (250, args.starts)
    isolation = detect_isolation()
    if not isolation.safe:
        sys.exit(f"needs the safe sandbox: {isolation.problem}")
    with tempfile.TemporaryDirectory(prefix="bench-images-") as tmp:
        root = Path(tmp)
        layout, archive = big_image(root, megabytes)
        print(f"cores: {os.cpu_count()}; load: {os.getloadavg()[0]:.1f}; image: "
              f"{archive.stat().st_size / 1e6:.0f} MB as docker save")
        for name, path in (("docker save", archive), ("OCI layout, gzip", layout)):
            cache = root / f"cache-{name[:3]}"
            t0 = time.perf_counter()
            image = unpack_image(path, cache)
            first = time.perf_counter() - t0
            t0 = time.perf_counter()
            unpack_image(path, cache)
            print(f"unpack {name}: first {first:.1f} s, cached {time.perf_counter() - t0:.2f} s "
                  f"({sum(f.stat().st_size for f in image.rootfs.rglob('*') if f.is_file()) / 1e6:.0f} MB)")
        image_cmd = image_spec("img", layout, isolation, cache=root / "cache-OCI", parent=None).command
        package = root / "package"
        package.mkdir()
        shutil.copy(AGENT, package / "agent.py")
        os.chmod(package, 0o755)
        os.chmod(package / "agent.py", 0o644)
        package_cmd = shlex.join(confine(["python3", "agent.py", "anywhere"], package, Limits(), isolation,
                                         parent=None))
        times: dict[str, list[float]] = {"image": [], "package": []}
        for _ in range(starts):
            times["image"].append(start_s(image_cmd))
            times["package"].append(start_s(package_cmd))
        for name, ts in times.items():
            print(f"start {name}: median {statistics.median(ts):.3f} s (min {min(ts):.3f}, max {max(ts):.3f})")


if __name__ == "__main__":
    main()
