"""Evaluator parts without a server: archive checks, the agent sandbox, the compliance checks, scores."""

from __future__ import annotations

import hashlib
import io
import math
import os
import socket
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import numpy as np
import pytest

from proxybench.agents.package import PackageError, check_archive, extract_archive
from proxybench.evaluator.compliance import check_calibration, check_frame, check_reality_model
from proxybench.evaluator.report import clean
from proxybench.evaluator.sandbox import ArchiveMismatch, Isolation, Limits, confine, detect_isolation, prepare_agent

MANIFEST = b"name: t\nprotocol: aido-z2\ncommand: [python3, agent.py]\n"


def _zip(members: dict[str, bytes], links: dict[str, str] | None = None) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
        for name, target in (links or {}).items():
            info = zipfile.ZipInfo(name)
            info.external_attr = (0o120777 << 16)  # a symbolic link, as `zip --symlinks` stores it
            zf.writestr(info, target)
    return buf.getvalue()


def _tar(members: dict[str, bytes], links: dict[str, str] | None = None, hard: bool = False) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tf:
        for name, data in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tf.addfile(info, io.BytesIO(data))
        for name, target in (links or {}).items():
            info = tarfile.TarInfo(name)
            info.type = tarfile.LNKTYPE if hard else tarfile.SYMTYPE
            info.linkname = target
            tf.addfile(info)
    return buf.getvalue()


# -- archives ---------------------------------------------------------------------------------------

@pytest.mark.parametrize("pack", [_zip, _tar])
@pytest.mark.parametrize("member", ["../evil.py", "a/../../evil.py", "/tmp/evil.py"])
def test_path_traversal_is_refused(tmp_path: Path, pack, member: str) -> None:
    data = pack({"proxybench-agent.yaml": MANIFEST, member: b"x"})
    with pytest.raises(PackageError, match="leaves the package folder"):
        check_archive(data)
    with pytest.raises(PackageError):
        extract_archive(data, tmp_path / "out")
    assert not (tmp_path / "evil.py").exists() and not (tmp_path / "out" / "evil.py").exists()


@pytest.mark.parametrize("data", [
    _zip({"proxybench-agent.yaml": MANIFEST}, {"agent.py": "/etc/passwd"}),
    _tar({"proxybench-agent.yaml": MANIFEST}, {"agent.py": "/etc/passwd"}),
    _tar({"proxybench-agent.yaml": MANIFEST}, {"agent.py": "../../outside"}, hard=True),
], ids=["zip-symlink", "tar-symlink", "tar-hardlink"])
def test_links_are_refused(tmp_path: Path, data: bytes) -> None:
    with pytest.raises(PackageError, match="links are not allowed"):
        check_archive(data)
    with pytest.raises(PackageError):
        extract_archive(data, tmp_path / "out")


def test_prepare_agent_checks_the_hash_then_unpacks(tmp_path: Path) -> None:
    data = _zip({"proxybench-agent.yaml": MANIFEST, "agent.py": b"print(1)", "lib/util.py": b""})
    with pytest.raises(ArchiveMismatch, match="refusing to run it"):
        prepare_agent(data, "0" * 64, tmp_path / "bad")
    manifest = prepare_agent(data, hashlib.sha256(data).hexdigest(), tmp_path / "good")
    assert manifest.command == ["python3", "agent.py"]
    assert (tmp_path / "good" / "lib" / "util.py").is_file()
    with pytest.raises(PackageError, match=r"no proxybench-agent\.yaml"):
        check_archive(_zip({"agent.py": b""}))


# -- the sandbox ------------------------------------------------------------------------------------

def _run(argv: list[str], folder: Path, limits: Limits, isolation: Isolation, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(confine(argv, folder, limits, isolation), capture_output=True, text=True, timeout=60, **kw)


@pytest.fixture(scope="module")
def isolation() -> Isolation:
    return detect_isolation("auto")


def test_sandbox_blocks_the_network(tmp_path: Path, isolation: Isolation) -> None:
    if not isolation.blocks_network:
        pytest.skip(f"no network isolation on this host ({isolation.note})")
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen()
        code = f"import socket; socket.create_connection(('127.0.0.1', {srv.getsockname()[1]}), timeout=3); print('in')"
        inside = _run(["python3", "-c", code], tmp_path, Limits(), isolation)
        outside = _run(["python3", "-c", code], tmp_path, Limits(), Isolation("none", drop_root=isolation.drop_root))
    assert inside.returncode != 0 and "in" not in inside.stdout
    assert "unreachable" in inside.stderr or "refused" in inside.stderr or "Errno" in inside.stderr
    assert outside.returncode == 0 and outside.stdout.strip() == "in"  # the same code does connect unconfined


def test_sandbox_limits_file_size_cpu_and_environment(tmp_path: Path, isolation: Isolation) -> None:
    limits = Limits(cpu_seconds=1, file_bytes=1 << 20)
    small = _run(["python3", "-c", "open('ok.bin', 'wb').write(b'x' * 500_000)"], tmp_path, limits, isolation)
    assert small.returncode == 0, small.stderr
    big = _run(["python3", "-c", "open('big.bin', 'wb').write(b'x' * 3_000_000)"], tmp_path, limits, isolation)
    assert big.returncode != 0 and ("File too large" in big.stderr or big.returncode == -25)  # EFBIG or SIGXFSZ
    assert (tmp_path / "big.bin").stat().st_size <= 1 << 20
    spin = _run(["python3", "-c", "while True: pass"], tmp_path, limits, isolation)
    assert spin.returncode in (-signal_number("SIGXCPU"), -signal_number("SIGKILL"))
    env = _run(["python3", "-c", "import os; print(os.getcwd()); print(sorted(os.environ))"], tmp_path, limits,
               isolation, env={**os.environ, "PROXYBENCH_TOKEN": "pbt_secret"})
    cwd, names = env.stdout.splitlines()
    assert Path(cwd) == tmp_path.resolve() and "PROXYBENCH_TOKEN" not in names and "'HOME'" in names


def signal_number(name: str) -> int:
    import signal

    return int(getattr(signal, name))


def test_python_means_the_evaluators_interpreter(tmp_path: Path) -> None:
    argv = confine(["python3", "agent.py"], tmp_path, Limits(), Isolation("none", drop_root=False))
    assert argv[argv.index("--") + 1:] == [sys.executable, "agent.py"]


# -- compliance and scores --------------------------------------------------------------------------

def test_frame_checks() -> None:
    from proxybench.protocol import jpeg

    rng = np.random.default_rng(0)
    good = jpeg.encode(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    assert check_frame(good, 64, 48).ok
    assert "expects 32×24" in check_frame(good, 32, 24).detail
    assert not check_frame(good[:-2], 64, 48).ok  # truncated: no end-of-image marker
    assert "blank" in check_frame(jpeg.encode(np.zeros((48, 64, 3), np.uint8)), 64, 48).detail
    assert not check_frame(b"\xff\xd8garbage\xff\xd9", 64, 48).ok


def test_calibration_and_reality_model_compliance() -> None:
    from proxybench.domain.params import DomainParams
    from proxybench.runner.evaluate import benchmark_domain
    from proxybench.tasks.benchmark import Benchmark

    spec = DomainParams()
    assert check_calibration({"trim": 0.05, "camera_pitch": 20.0}, spec).ok
    bad = check_calibration({"trim": 0.3, "camera_height": 0.2}, spec)
    assert not bad.ok and "trim" in bad.detail and "camera_height" in bad.detail
    bench = Benchmark.load("aido_lf")
    target = DomainParams.model_validate(benchmark_domain(bench, "reality").params)
    report = check_reality_model(bench, target)
    assert report.ok, report.failures()
    assert report.domain_kind == "reality-model" and "not a real robot" in report.target
    small = bench.model_copy(update={"domain": bench.domain.model_copy(
        update={"params": bench.domain.params.replace(image_width=160, image_height=120)})})
    mismatch = check_reality_model(small, target)
    assert not mismatch.ok and "expects 160×120" in mismatch.failures()


def test_scores_are_json_clean() -> None:
    assert clean(float("nan")) is None and clean(math.inf) is None and clean(None) is None
    assert clean(np.float64(1.5)) == 1.5


@pytest.mark.slow
def test_target_on_a_robot_node(tmp_path: Path) -> None:
    """A simulator served as a robot node: compliant, and it runs the episodes; reports never call it a robot."""
    from proxybench.evaluator.report import summarize
    from proxybench.evaluator.robot import check_robot, evaluate_on_robot
    from proxybench.runner.jobs import AgentSpec
    from proxybench.tasks.benchmark import Benchmark

    bench = Benchmark.from_dict({
        "name": "tiny_robot", "map": "small_loop", "episodes": {"count": 1, "seed": 1}, "duration": 1.0,
        "physics_rate": 30.0, "frame_rate": 5.0, "metrics": ["survival_time"],
        "scoring": [{"metric": "survival_time_median"}]})
    cmd = f"{sys.executable} -m proxybench robot serve --map small_loop --param frame_rate=5 --param physics_rate=30"
    report = check_robot(bench, cmd)
    assert report.ok, report.failures()
    assert report.domain_kind == "robot-node/simulation" and "says it is: simulation" in report.target
    ev = evaluate_on_robot(bench, AgentSpec("pid"), cmd, tmp_path / "run")
    summary = summarize(ev, "validation", domain_kind=report.domain_kind)
    assert summary.problems == [] and summary.failures == []
    assert summary.scores["survival_time_median"] == pytest.approx(1.0)
