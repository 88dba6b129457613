"""Faults in an Autolab (issue 36, "Done when"): each ends with the right status and reason, and nothing is lost.

- a watchtower stream stops mid-episode (the lab's drill): the run is invalid, the job goes back to the queue;
- the agent crashes: the job fails with the agent's last words, one result;
- the robot's DTPS endpoint (the virtual DB21J's bridge) dies mid-episode: ``robot_failure``, back in the queue,
  though the agent program lost its robot too;
- the Autolab evaluator is killed (-9) mid-job: its lease lapses, another Autolab evaluator runs the job, one
  result.

The server and package helpers are test_evaluator's and test_autolab_evaluator's (one short episode).
"""

from __future__ import annotations

import io
import os
import signal
import threading
import time
import zipfile
from pathlib import Path

import pytest

pytest.importorskip("fastapi")
pytest.importorskip("uvicorn")

from proxybench.cli.autolab_demo import LANE_AGENT
from support.dtps import sdk
from support.sandbox import AGENT_USER_GROUP, processes_left, require_safe_sandbox
from test_autolab_evaluator import BENCH, LAB, sdk_package
from test_evaluator import Served, evaluator, served, start_cli_evaluator, the_job  # noqa: F401 - served: fixture

pytestmark = [AGENT_USER_GROUP, sdk]

#: the lane follower, crashing at its 10th camera frame: 2 s into the episode (the agent contract before it feeds
#: a second of frames, 5)
CRASH = LANE_AGENT.replace(
    "while True:\n", "frames = 0\nwhile True:\n    frames += 1\n"
    "    if frames == 10:\n        raise ZeroDivisionError('my lane agent divided by zero')\n", 1)


def _setup(srv: Served, tmp_path: Path, lab: str = LAB, bench: str = BENCH, package: bytes | None = None) -> dict:
    srv.admin.post("/benchmarks", {"yaml": bench, "features": ["autolab"], "hidden_split": False})
    (tmp_path / "lab.yaml").write_text(lab)
    archive = tmp_path / "agent.zip"
    archive.write_bytes(package or sdk_package())
    return srv.developer.submit_archive(archive, "sdk-lane", benchmark="autolab_tiny")


def _lab_evaluator(srv: Served, tmp_path: Path, name: str = "lab"):
    from proxybench.autolab.lab import load_lab

    return evaluator(srv, tmp_path, name=name, video=False, features=("sim", "autolab"),
                     autolab=load_lab(tmp_path / "lab.yaml"))


def _host_error(srv: Served, job_id: int) -> str:
    (event,) = [e for e in srv.admin.get(f"/jobs/{job_id}")["events"] if e["kind"] == "host-error"]
    return event["message"]


def test_watchtower_streams_that_stop_mid_episode_make_the_run_invalid_and_the_job_goes_back(
        served: Served, tmp_path: Path) -> None:  # noqa: F811
    require_safe_sandbox()
    sub = _setup(served, tmp_path, LAB + "drills: {streams_stop_s: 1.5}\n")
    ev = _lab_evaluator(served, tmp_path)
    assert ev.take_one() == "host-error"
    job, results = the_job(served, sub["id"])
    assert job["status"] == "queued" and results == []  # the lab's fault: nothing stored, another lab may run it
    message = _host_error(served, job["id"])
    assert message.startswith("invalid: validation episode 0 is not fit to be scored (the DTA's validation)"), message
    assert "ended prematurely: recorded 1.4 s of 3 s" in message  # the last frames at or before 1.5 s
    assert ev.take_one() is None  # this lab is excluded from the job now


def test_one_stopped_stream_of_many_costs_nothing(tmp_path: Path) -> None:
    """The drill on one watchtower: its recording ends, the other eleven's do not (the localisation is theirs)."""
    import csv

    from proxybench.autolab.lab import load_lab
    from proxybench.evaluator.autolab import stop_streams

    (tmp_path / "lab.yaml").write_text(LAB + "drills: {streams_stop_s: 0.5, streams_stop: [wt01]}\n")
    streams = tmp_path / "streams"
    for name in ("wt01", "wt02"):
        (streams / name).mkdir(parents=True)
        for k in range(5):
            (streams / name / f"{k:06d}.jpg").write_bytes(b"jpeg")
        (streams / name / "timestamps.csv").write_text("frame,t\n" + "".join(f"{k},{0.2 * k:.6f}\n"
                                                                              for k in range(5)))
    assert stop_streams(streams, load_lab(tmp_path / "lab.yaml")) == ["wt01"]
    with open(streams / "wt01" / "timestamps.csv") as fh:
        assert [r["frame"] for r in csv.DictReader(fh)] == ["0", "1", "2"]
    assert sorted(p.name for p in (streams / "wt01").glob("*.jpg")) == ["000000.jpg", "000001.jpg", "000002.jpg"]
    assert len(list((streams / "wt02").glob("*.jpg"))) == 5


def _package(source: str) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        zf.writestr("proxybench-agent.yaml", "name: sdk-lane\nprotocol: duckietown-sdk\ncommand: python3 lane.py\n"
                                             "timing: lockstep\nstart_timeout: 120\n")
        zf.writestr("lane.py", source)
    return buf.getvalue()


def test_an_agent_that_crashes_fails_its_job_with_its_last_words(served: Served, tmp_path: Path) -> None:  # noqa: F811
    require_safe_sandbox()
    sub = _setup(served, tmp_path, package=_package(CRASH))
    ev = _lab_evaluator(served, tmp_path)
    assert ev.take_one() == "failed"
    job, (result,) = the_job(served, sub["id"])
    assert job["status"] == "failed" and result["status"] == "failed"
    assert "my lane agent divided by zero" in result["message"], result["message"]
    assert "robot_failure" not in result["message"]
    assert processes_left(require_safe_sandbox().uid, 10) == []


def _parent(pid: int) -> int:
    try:
        stat = (Path("/proc") / str(pid) / "stat").read_text()
    except OSError:
        return 0
    return int(stat.rsplit(")", 1)[1].split()[1])  # the field after the state; the name may hold spaces


def _ours(pid: int) -> bool:
    """Whether ``pid`` descends from this test process (another test's bridge, in the other xdist worker or
    another suite on the machine, is not ours to kill)."""
    me = os.getpid()
    while pid > 1:
        pid = _parent(pid)
        if pid == me:
            return True
    return False


def _bridges() -> list[int]:
    """This test's running virtual DB21J bridges (the robot's DTPS server: ``dtps/bridge.py server``)."""
    out = []
    for p in Path("/proc").iterdir():
        if not p.name.isdigit():
            continue
        try:
            cmd = (p / "cmdline").read_bytes().split(b"\0")
        except OSError:
            continue
        if any(c.endswith(b"dtps/bridge.py") for c in cmd) and b"server" in cmd and _ours(int(p.name)):
            out.append(int(p.name))
    return out


def _episode_frames(work: Path, count: int) -> bool:
    """Whether the watchtowers have recorded ``count`` frames of a validation episode (it is under way)."""
    return any(work.glob(f"job-*/runs/validation/**/*.streams/*/{count:06d}.jpg"))


def test_a_robot_whose_dtps_endpoint_dies_mid_episode_is_a_robot_failure(served: Served,  # noqa: F811
                                                                         tmp_path: Path) -> None:
    require_safe_sandbox()
    sub = _setup(served, tmp_path, bench=BENCH.replace("duration: 3.0", "duration: 8.0"))
    ev = _lab_evaluator(served, tmp_path)
    statuses: list[str | None] = []
    runner = threading.Thread(target=lambda: statuses.append(ev.take_one()))
    runner.start()
    killed = []
    deadline = time.monotonic() + 300  # a guard against a hang, not a speed limit
    while runner.is_alive() and not killed and time.monotonic() < deadline:
        if _episode_frames(tmp_path / "work-lab", 5):
            for pid in _bridges():
                os.kill(pid, signal.SIGKILL)
                killed.append(pid)
        time.sleep(0.05)
    runner.join(300)
    assert killed, "the episode never got under way"
    assert statuses == ["host-error"]
    job, results = the_job(served, sub["id"])
    assert job["status"] == "queued" and results == []
    message = _host_error(served, job["id"])
    assert message.startswith("robot_failure: lab 'test-lab''s robot 'db1' failed in validation episode 0"), message
    assert "DTPS server (bridge) died" in message
    assert processes_left(require_safe_sandbox().uid, 10) == []


def test_a_killed_autolab_evaluator_s_job_is_run_again_once(served: Served, tmp_path: Path) -> None:  # noqa: F811
    require_safe_sandbox()
    sub = _setup(served, tmp_path, bench=BENCH.replace("duration: 3.0", "duration: 8.0"))
    proc, work = start_cli_evaluator(served, tmp_path, "victim", "--once", "--autolab", str(tmp_path / "lab.yaml"))
    try:
        deadline = time.monotonic() + 300  # a guard against a hang, not a speed limit
        while not _episode_frames(work, 3):
            assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
            assert time.monotonic() < deadline, "the Autolab evaluator never got its episode under way"
            time.sleep(0.05)
        job, _ = the_job(served, sub["id"])
        assert job["status"] == "evaluating" and job["evaluator"] == "victim"
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert processes_left(require_safe_sandbox().uid, 10) == [], "the agent outlived the killed evaluator"
    rescuer = _lab_evaluator(served, tmp_path, name="rescuer")
    deadline = time.monotonic() + 60
    status = None
    while status is None:
        assert time.monotonic() < deadline, "the lapsed lease never came back to the queue"
        status = rescuer.take_one()
        time.sleep(0.2)
    assert status == "success"
    job, results = the_job(served, sub["id"])
    assert job["status"] == "success" and job["attempts"] == 2 and job["evaluator"] == "rescuer"
    assert len(results) == 1 and results[0]["public_report"]["measured_by"] == "watchtowers"
    assert "lease-lapsed" in [e["kind"] for e in served.admin.get(f"/jobs/{job['id']}")["events"]]
