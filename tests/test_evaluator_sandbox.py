"""Evaluator parts without a server: archive checks, the agent sandbox, the compliance checks, scores."""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import math
import os
import socket
import subprocess
import sys
import tarfile
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest

from proxybench.evaluator.compliance import check_calibration, check_frame, check_reality_model
from proxybench.evaluator.report import clean
from proxybench.evaluator.sandbox import (
    ArchiveMismatch,
    Isolation,
    Limits,
    SandboxError,
    confine,
    detect_isolation,
    prepare_agent,
)
from proxybench.protocol.package import PackageError, check_archive
from proxybench.protocol.unpack import extract_archive
from support.jobs import worker_job
from support.sandbox import AGENT_USER_GROUP, require_safe_sandbox

pytestmark = AGENT_USER_GROUP  # its agents and evaluators run as the agent user: one test at a time

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

FACTS = """\
import ctypes, json, os, resource, socket, sys
facts = {"uid": os.getuid(), "euid": os.geteuid(), "cwd": os.getcwd(), "env": sorted(os.environ),
         "home": os.environ.get("HOME"), "root": sorted(os.listdir("/")), "pids": [p for p in os.listdir("/proc")
         if p.isdigit()], "nproc": resource.getrlimit(resource.RLIMIT_NPROC)[0]}
status = dict(line.split(":", 1) for line in open("/proc/self/status") if ":" in line)
facts.update(caps=status["CapEff"].strip(), bounding=status["CapBnd"].strip(), nnp=status["NoNewPrivs"].strip())
for name, path in (("package", "x"), ("scratch", "/scratch/x"), ("tmp", "/tmp/x"), ("shm", "/dev/shm/x")):
    try:
        open(path, "w").write("x"); facts[name] = "writable"
    except OSError as exc:
        facts[name] = exc.strerror
try:
    socket.create_connection(("127.0.0.1", int(sys.argv[1])), timeout=3); facts["net"] = "connected"
except OSError as exc:
    facts["net"] = str(exc)
facts["userns"] = ctypes.CDLL(None).unshare(0x10000000)
print(json.dumps(facts))
"""


def _package(tmp_path: Path, files: dict[str, str]) -> Path:
    folder = tmp_path / "agent"
    folder.mkdir()
    for name, text in files.items():
        (folder / name).write_text(text)
    folder.chmod(0o755)
    for p in folder.iterdir():
        p.chmod(0o644)
    return folder


def _run(argv: list[str], folder: Path, limits: Limits, isolation: Isolation, **kw) -> subprocess.CompletedProcess:
    return subprocess.run(confine(argv, folder, limits, isolation, parent=None), capture_output=True, text=True,
                          timeout=60, **kw)


@pytest.fixture(scope="module")
def isolation() -> Isolation:
    return require_safe_sandbox()


def test_agents_run_as_the_agent_user_with_nothing_of_the_evaluator(tmp_path: Path, isolation: Isolation) -> None:
    import json

    folder = _package(tmp_path, {"facts.py": FACTS})
    with socket.socket() as srv:
        srv.bind(("127.0.0.1", 0))
        srv.listen()
        done = _run(["python3", "facts.py", str(srv.getsockname()[1])], folder, Limits(processes=64), isolation,
                    env={**os.environ, "PROXYBENCH_TOKEN": "pbt_secret"})
    assert done.returncode == 0, done.stderr
    facts = json.loads(done.stdout)
    assert facts["uid"] == facts["euid"] == isolation.uid != 0 and facts["uid"] != os.geteuid()
    assert facts["caps"] == facts["bounding"] == "0000000000000000" and facts["nnp"] == "1"
    assert facts["userns"] != 0  # no user namespace of its own (the way to capabilities inside)
    assert facts["pids"] == ["1", "2"]  # bubblewrap's init and the agent: nothing else of the host
    assert facts["cwd"] == "/agent" and facts["package"] == "Read-only file system"
    assert facts["scratch"] == facts["tmp"] == facts["shm"] == "writable" and facts["home"] == "/scratch"
    assert "PROXYBENCH_TOKEN" not in facts["env"]
    assert set(facts["root"]) <= {"agent", "scratch", "tmp", "dev", "proc", "etc", "usr", "bin", "sbin", "lib",
                                  "lib32", "lib64", "libx32", *(p.split("/")[1] for p in isolation.runtime)}
    assert "refused" in facts["net"] or "unreachable" in facts["net"]
    assert 64 <= facts["nproc"] < 64 + 1000  # the agent user's threads now, plus 64


def test_runtime_behind_a_closed_folder_is_visible_alone(tmp_path: Path, isolation: Isolation) -> None:
    """The issue's failure: the runtime in a home folder the agent user may not enter. Staged, it works; the
    rest of that folder stays out of sight."""
    home = tmp_path / "home"
    (home / "runtime").mkdir(parents=True)
    home.chmod(0o700)
    (home / "runtime" / "helper.py").write_text("VALUE = 42\n")
    (home / "runtime" / "helper.py").chmod(0o644)
    (home / "secret.txt").write_text("not for agents")
    (home / "secret.txt").chmod(0o644)
    mine = dataclasses.replace(isolation, runtime=(*isolation.runtime, str(home / "runtime")))
    code = (f"import sys; sys.path.insert(0, {str(home / 'runtime')!r}); import helper; print(helper.VALUE); "
            f"print(open({str(home / 'secret.txt')!r}).read())")
    done = _run(["python3", "-c", code], _package(tmp_path, {}), Limits(), mine)
    assert done.stdout.startswith("42\n") and "No such file" in done.stderr and "not for agents" not in done.stdout


def test_limits_cpu_file_size_scratch_and_memory(tmp_path: Path, isolation: Isolation) -> None:
    limits = Limits(cpu_seconds=1, file_bytes=2 << 20, scratch_bytes=4 << 20, tmp_bytes=1 << 20,
                    memory_bytes=512 << 20)
    folder = _package(tmp_path, {})
    big = _run(["python3", "-c", "open('/scratch/big', 'wb').write(b'x' * 3_000_000)"], folder, limits, isolation)
    assert big.returncode != 0 and ("File too large" in big.stderr or big.returncode in (-25, 128 + 25))
    fill = ("import os\nn = 0\ntry:\n    while True:\n        f = open(f'/scratch/f{n}', 'wb'); "
            "f.write(b'x' * 1_000_000); f.close(); n += 1\nexcept OSError as e:\n    print(n, e.strerror)")
    out = _run(["python3", "-c", fill], folder, limits, isolation).stdout.split(maxsplit=1)
    assert int(out[0]) <= 4 and "No space left" in out[1]
    shm = _run(["python3", "-c", "open('/dev/shm/x', 'wb').write(b'x' * 2_000_000)"], folder, limits, isolation)
    assert "No space left" in shm.stderr
    spin = _run(["python3", "-c", "while True: pass"], folder, limits, isolation)
    assert spin.returncode in (-24, -9, 128 + 24, 128 + 9)  # SIGXCPU, then SIGKILL
    hog = _run(["python3", "-c", "x = bytearray(1 << 30)"], folder, limits, isolation)
    assert "MemoryError" in hog.stderr


def test_python_means_the_evaluators_interpreter(tmp_path: Path) -> None:
    argv = confine(["python3", "agent.py"], tmp_path, Limits(), Isolation("none", "me"))
    assert argv[argv.index("--") + 1:] == [os.path.abspath(sys.executable), "agent.py"]


def test_without_the_agent_user_packages_are_refused_with_the_fix(monkeypatch) -> None:
    missing = detect_isolation.__wrapped__("no-such-agent-user")
    assert not missing.usable and "proxybench sandbox setup" in missing.problem
    with pytest.raises(SandboxError, match="no-such-agent-user"):
        confine(["python3", "x.py"], "/tmp", Limits(), missing)
    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    not_root = detect_isolation.__wrapped__()
    assert not not_root.usable and "not root" in not_root.problem


def test_the_developer_flag_says_unsafe() -> None:
    unsafe = detect_isolation.__wrapped__("no-such-agent-user", dev_unsafe=True)
    assert unsafe.usable and not unsafe.safe and unsafe.note.startswith("UNSAFE developer mode")
    assert unsafe.report()["safe"] is False


# -- the FIFO transport in the sandbox -----------------------------------------------------------------

NODE = Path(__file__).resolve().parent / "protocol_agents" / "zuper311_like.py"
FIFO_FACTS = """\
import json, os
facts = {"uid": os.getuid(), "fifo": sorted(os.listdir("/fifo")), "in": os.environ.get("AIDONODE_DATA_IN"),
         "out": os.environ.get("AIDONODE_DATA_OUT"), "root": sorted(os.listdir("/"))}
for name, attempt in (("create", lambda: open("/fifo/x", "w")), ("replace", lambda: os.unlink("/fifo/out")),
                      ("link", lambda: os.symlink("/etc/shadow", "/fifo/y"))):
    try:
        attempt()
        facts[name] = "done"
    except OSError as exc:
        facts[name] = exc.strerror
print("FACTS " + json.dumps(facts), flush=True)  # to stdout: over FIFOs that cannot break the protocol
"""


def test_a_fifo_package_printing_to_stdout_runs_in_the_sandbox(tmp_path: Path, isolation: Isolation) -> None:
    """A manifest's ``transport: fifo`` through the evaluator's own path: the node, as the agent user, finds its
    two FIFOs read-only at /fifo and prints to stdout freely; nothing else of the job folder is in view."""
    from proxybench.agents.base import Observation
    from proxybench.evaluator.report import summarize
    from proxybench.evaluator.run import _Job
    from proxybench.runner.outcomes import make_agent_for
    from proxybench.tasks.benchmark import Benchmark

    manifest = (b"name: printer\nprotocol: aido-z2\ntransport: fifo\nreflection: false\ncommand: python3 facts.py "
                b"&& exec python3 solution.py --print --starts-log /scratch/starts.log\n")
    data = _zip({"proxybench-agent.yaml": manifest, "facts.py": FIFO_FACTS.encode(), "solution.py": NODE.read_bytes()})
    job_dir = tmp_path / "job"
    job_dir.mkdir(mode=0o700)
    (job_dir / "agent.archive").write_bytes(data)
    (job_dir / "job.json").write_text('{"hidden_seed": 123}')
    job = _Job(job_dir, worker_job(isolation, archive_sha256=hashlib.sha256(data).hexdigest(), limits=Limits()))
    spec = job.agent(None)
    assert spec.node_options().transport == "fifo"
    agent = make_agent_for(spec)
    try:
        agent.reset(seed=1)
        for k in range(3):
            out = agent.act(Observation(np.zeros((12, 16, 3), np.uint8), k / 15, (0.0, 0.0), 0.01))
        assert list(out) == [0.2, 0.25]
    finally:
        agent.close()
    drain = agent.process._os.stderr  # read after the end: the drain thread has seen every line by then
    deadline = time.monotonic() + 10
    while not any("FACTS" in line for line in drain.tail()) and time.monotonic() < deadline:
        time.sleep(0.05)  # (a loaded machine may schedule the drain thread late)
    tail = drain.tail()
    assert any("loading the model" in line for line in tail), tail  # its stdout: beside the protocol, not in it
    facts = json.loads(next(line for line in tail if line.startswith("FACTS "))[6:])
    assert facts["uid"] == isolation.uid and facts["in"] == "/fifo/in" and facts["out"] == "fifo:/fifo/out"
    assert facts["fifo"] == ["in", "out"]
    assert set(facts["root"]) <= {"agent", "fifo", "scratch", "tmp", "dev", "proc", "etc", "usr", "bin", "sbin", "lib",
                                  "lib32", "lib64", "libx32", *(p.split("/")[1] for p in isolation.runtime)}
    assert facts["create"] == facts["replace"] == facts["link"] == "Read-only file system"
    fifos = job_dir / "agent.fifos"
    assert (fifos.stat().st_mode & 0o777) == 0o700 and list(fifos.iterdir()) == []  # each start's folder removed
    bench = Benchmark.from_dict({
        "name": "tiny_fifo", "map": "small_loop", "episodes": {"count": 1, "seed": 1}, "duration": 1.0,
        "physics_rate": 30.0, "frame_rate": 5.0, "metrics": ["survival_time"],
        "scoring": [{"metric": "survival_time_median"}]})
    summary = summarize(job.evaluate(bench, spec, "validation", False), "validation", domain_kind="simulation")
    assert summary.failures == [] and summary.problems == []


def test_the_shim_shows_only_a_fifo_folder_directly_in_its_root(tmp_path: Path) -> None:
    """The shim checks what the caller names before showing it: a folder elsewhere (or a link out of the root)
    is refused, so the FIFO transport can never widen the agent's view."""
    root, elsewhere = tmp_path / "fifos", tmp_path / "elsewhere"
    root.mkdir()
    elsewhere.mkdir()
    for name in ("in", "out"):
        os.mkfifo(elsewhere / name)
    (root / "link").symlink_to(elsewhere)
    argv = confine(["python3", "-c", "pass"], _package(tmp_path, {}), Limits(), Isolation("none", "me"),
                   parent=None, fifo_root=root)
    for folder in (elsewhere, root / "link"):
        env = {**os.environ, "AIDONODE_DATA_IN": f"{folder}/in", "AIDONODE_DATA_OUT": f"fifo:{folder}/out"}
        done = subprocess.run(argv, capture_output=True, text=True, timeout=30, env=env)
        assert done.returncode == 126 and "not a folder directly inside --fifo-root" in done.stderr
    env = {**os.environ, "AIDONODE_DATA_IN": f"{elsewhere}/in", "AIDONODE_DATA_OUT": "fifo:/etc/out"}
    done = subprocess.run(argv, capture_output=True, text=True, timeout=30, env=env)
    assert done.returncode == 126 and "must be FOLDER/in and fifo:FOLDER/out" in done.stderr


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
    target = benchmark_domain(bench, "reality").params
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
    """A simulator served as a robot node: compliant, and it runs the episodes through the runner (cached,
    resumable, with the benchmark's routes); reports never call it a robot."""
    from proxybench.evaluator.compliance import check_robot
    from proxybench.evaluator.report import summarize
    from proxybench.runner.evaluate import evaluate_benchmark
    from proxybench.runner.jobs import AgentSpec, DomainSpec
    from proxybench.tasks.benchmark import Benchmark
    from proxybench.tasks.trajectory import Trajectory

    bench = Benchmark.from_dict({
        "name": "tiny_robot", "map": "small_loop", "episodes": {"count": 1, "seed": 1, "routes": [["left"]]},
        "duration": 1.0, "physics_rate": 30.0, "frame_rate": 5.0, "metrics": ["survival_time"],
        "scoring": [{"metric": "survival_time_median"}]})
    cmd = f"{sys.executable} -m proxybench robot serve --map small_loop --param frame_rate=5 --param physics_rate=30"
    report = check_robot(bench, cmd)
    assert report.ok, report.failures()
    assert report.domain_kind == "robot-node/simulation" and "says it is: simulation" in report.target
    robot = DomainSpec.robot(cmd, frame_rate=bench.frame_rate)
    ev = evaluate_benchmark(bench, [AgentSpec("pid")], tmp_path / "run", domain=robot)
    summary = summarize(ev, "validation", domain_kind=report.domain_kind)
    assert summary.problems == [] and summary.failures == []
    assert summary.scores["survival_time_median"] == pytest.approx(1.0)
    (result,) = ev.sweep.results
    assert Trajectory.load(result.trajectory).meta["route_plan"] == ["left"]  # the benchmark's route reached it
    again = evaluate_benchmark(bench, [AgentSpec("pid")], tmp_path / "run", domain=robot)
    assert again.sweep.cached == 1 and again.sweep.ran == 0  # resumed from the cache: the robot was not driven


def test_an_agent_cannot_pass_its_failure_off_as_the_hosts(tmp_path: Path, isolation: Isolation) -> None:
    """Sandbox words on an agent's stderr make the worker probe the sandbox: working → the agent's fault."""
    from proxybench.evaluator.outcome import HostFault
    from proxybench.evaluator.run import _Job

    tail = [["bwrap: Creating new namespace failed: No space left on device"]]
    _Job(tmp_path, worker_job(isolation)).check_sandbox(tail)  # no fault
    broken = dataclasses.replace(isolation, bwrap="/bin/false")
    with pytest.raises(HostFault, match="the sandbox stopped working on this host"):
        _Job(tmp_path, worker_job(broken)).check_sandbox(tail)


def test_the_evaluator_uploads_only_files_of_the_job_folder(tmp_path: Path) -> None:
    """Even an outcome naming /etc/shadow or a link to it (say, from a buggy worker) uploads nothing of it."""
    from proxybench.evaluator.outcome import Artifact, Outcome
    from proxybench.evaluator.workdir import StateDir
    from proxybench.evaluator.worker import job_artifacts_only

    state = StateDir(tmp_path / "work")
    folder = state.new_job("job")
    job = folder.path
    (job / "evaluator.log").write_text("fine")
    (job / "trajectories-validation.zip").symlink_to("/etc/passwd")
    zipped = "trajectories-validation.zip"
    sent = Outcome("success", artifacts=[Artifact("evaluator.log", str(job / "evaluator.log")),
                                         Artifact("shadow", "/etc/shadow"),
                                         Artifact("../evaluator.log", str(job / "../evaluator.log")),
                                         Artifact(zipped, str(job / zipped))])
    kept = job_artifacts_only(Outcome.parse(json.dumps(dataclasses.asdict(sent))), job)
    assert [a.name for a in kept.artifacts] == ["evaluator.log", "trajectories-validation.zip"]
    assert "'shadow' refused" in kept.message and "'../evaluator.log' refused" in kept.message
    assert folder.read("evaluator.log") == b"fine"
    with pytest.raises(OSError):  # a link is never followed when uploading
        folder.read("trajectories-validation.zip")
    state.close()
    with pytest.raises(ValueError, match="unknown status"):
        Outcome.parse('{"status": "rank-1"}')
